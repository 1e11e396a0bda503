"""bench.count_step_operators: the dispatch hook counts operators and names the host reads."""

import importlib

import torch


def test_census_counts_operators_and_the_reads_that_wait_for_a_device():
    census_cls = importlib.import_module("bench.count_step_operators").OperatorCensus
    x = torch.arange(10.0, requires_grad=True)
    census = census_cls()
    with census:
        y = (x * 2.0)[x.detach() > 3]  # boolean mask: a host read on CUDA
        n = int(torch.nonzero(y > 10).shape[0])  # nonzero: a host read (its size)
        s = float(y.sum())  # scalar read
        y.sum().backward()
    assert n == 4 and s == 78.0  # 2 * (4 + ... + 9)
    kinds = sorted(k.rsplit(" ", 1)[1] for k in census.host_reads)
    # The mask's backward is an index_put with the same mask: a host read too.
    assert kinds == ["_local_scalar_dense", "index[bool]", "index_put[bool]", "nonzero"]
    assert sum(census.by_file.values()) >= 8  # mul, gt, index, gt, nonzero, sum, item, sum, backward ops
    plain = census_cls()
    with plain:
        torch.ones(3).add_(1.0).index_select(0, torch.tensor([0, 2]))  # integer indexing: no host read
    assert not plain.host_reads
