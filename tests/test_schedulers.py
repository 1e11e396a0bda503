"""The Table-10 schedule: same curve as nerfstudio's, but checkpoints hold plain floats."""

import io

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")


@pytest.mark.parametrize("warmup,lr_final", [(0, 1.6e-6), (500, 1e-3), (1500, 1e-4)])
def test_matches_nerfstudio_curve_and_checkpoints_load_weights_only(warmup, lr_final):
    from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig as NsConfig

    from idsplat_ns.nerfstudio.schedulers import ExponentialDecaySchedulerConfig

    def run(config):
        param = torch.nn.Parameter(torch.zeros(1))
        opt = torch.optim.Adam([param], lr=1.6e-4 if lr_final < 1e-5 else 1e-3)
        sched = config.setup().get_scheduler(opt, opt.param_groups[0]["lr"])
        lrs = []
        for _ in range(3000):
            opt.step()
            sched.step()
            lrs.append(opt.param_groups[0]["lr"])
        return np.array(lrs, dtype=np.float64), opt

    kwargs = dict(lr_final=lr_final, warmup_steps=warmup, max_steps=3000)
    ours, opt = run(ExponentialDecaySchedulerConfig(**kwargs))
    ref, _ = run(NsConfig(**kwargs))
    np.testing.assert_allclose(ours, ref, rtol=1e-9)
    buffer = io.BytesIO()
    torch.save({"optimizer": opt.state_dict()}, buffer)
    buffer.seek(0)
    torch.load(buffer, weights_only=True)  # nerfstudio's own schedule fails here (numpy scalars)
