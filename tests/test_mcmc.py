"""MCMC densification: relocation formula, relocation/growth with instance ids and optimiser state,
noise gating, regularisation, schedule."""

from __future__ import annotations

import math

import mpmath
import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.mcmc import (
    MCMCConfig,
    MCMCDensifier,
    add_new,
    inject_noise,
    mcmc_regularisation,
    relocate_dead,
)
from idsplat_ns.model.mcmc_relocation import (
    relocation_denominator,
    relocation_update,
    sample_proportional,
)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def paper_relocation(o: float, s: float, n: int) -> tuple[float, float]:
    """Eq. 9 of Kheradmand et al. evaluated literally (double sum) at 60 digits."""
    mpmath.mp.dps = 60
    o = mpmath.mpf(o)
    o_new = 1 - (1 - o) ** (mpmath.mpf(1) / n)
    denom = mpmath.mpf(0)
    for i in range(1, n + 1):
        for k in range(i):
            denom += math.comb(i - 1, k) * (-1) ** k * o_new ** (k + 1) / mpmath.sqrt(k + 1)
    return float(o_new), float(o / denom * s)


def make_gaussians(opacities: list[float], ids: list[int], means: torch.Tensor, device: str = "cpu") -> GaussianSet:
    g = GaussianSet(len(opacities)).to(device)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        g.means.copy_(means)
        g.opacities.copy_(torch.logit(torch.tensor(opacities)))
        g.scales.copy_(torch.log(torch.rand(len(opacities), 3, generator=gen) * 0.2 + 0.05))
        q = torch.randn(len(opacities), 4, generator=gen)
        g.quats.copy_(q / q.norm(dim=1, keepdim=True))
        g.features_rgb.copy_(torch.randn(len(opacities), 3, generator=gen))
        g.features.copy_(torch.randn(len(opacities), 13, generator=gen))
        g.instance_ids.copy_(torch.tensor(ids))
    return g


def two_instance_scene(device: str = "cpu") -> GaussianSet:
    """Static Gaussians near (0, 50, 0), instance 1 near (10, 0, 0), instance 2 near (-10, 0, 0)
    (canonical coordinates); a third of each group dead."""
    gen = torch.Generator().manual_seed(0)
    centres = {0: (0.0, 50.0, 0.0), 1: (10.0, 0.0, 0.0), 2: (-10.0, 0.0, 0.0)}
    opacities, ids, means = [], [], []
    for k, c in centres.items():
        for j in range(30):
            ids.append(k)
            opacities.append(0.001 if j % 3 == 0 else 0.05 + 0.9 * j / 30)
            means.append(torch.tensor(c) + torch.randn(3, generator=gen))
    return make_gaussians(opacities, ids, torch.stack(means), device)


def adam_for(g: GaussianSet) -> dict[str, torch.optim.Optimizer]:
    return {name: torch.optim.Adam([getattr(g, name)], lr=1e-3) for name in g.PARAM_NAMES}


def fake_train_step(g: GaussianSet, optimizers: dict[str, torch.optim.Optimizer]) -> None:
    for opt in optimizers.values():
        opt.zero_grad()
    loss = sum((getattr(g, name) ** 2).sum() for name in g.PARAM_NAMES)
    loss.backward()
    for opt in optimizers.values():
        opt.step()


# ------------------------------------------------------------------------------------------
# Formula


@pytest.mark.parametrize("n", [1, 2, 3, 7, 20, 51])
@pytest.mark.parametrize("o", [0.006, 0.3, 0.9, 0.999])
def test_relocation_update_matches_paper_formula(o: float, n: int) -> None:
    expected_o, expected_s = paper_relocation(o, 0.7, n)
    new_o, new_s = relocation_update(
        torch.tensor([o], dtype=torch.float64), torch.full((1, 3), 0.7, dtype=torch.float64), torch.tensor([n])
    )
    assert new_o.item() == pytest.approx(expected_o, rel=1e-10)
    assert new_s[0].tolist() == pytest.approx([expected_s] * 3, rel=1e-8)


def test_relocation_update_vectorised_and_identity_for_single() -> None:
    o = torch.tensor([0.2, 0.95, 0.5, 0.02])
    s = torch.tensor([[0.1, 0.2, 0.3], [1.0, 1.0, 2.0], [0.5, 0.5, 0.5], [3.0, 1.0, 0.2]])
    n = torch.tensor([1, 4, 2, 150])
    new_o, new_s = relocation_update(o, s, n)
    assert new_o.dtype == torch.float32 and new_s.shape == (4, 3)
    # n = 1 leaves a Gaussian unchanged.
    assert new_o[0].item() == pytest.approx(0.2, rel=1e-6)
    assert new_s[0].tolist() == pytest.approx([0.1, 0.2, 0.3], rel=1e-6)
    for i in (1, 2):
        eo, es = paper_relocation(float(o[i]), 1.0, int(n[i]))
        assert new_o[i].item() == pytest.approx(eo, rel=1e-6)
        assert (new_s[i] / s[i]).tolist() == pytest.approx([es] * 3, rel=1e-5)
    # Group opacity is conserved: 1 - (1 - o_new)^n = o, also for n beyond gsplat's cap of 51.
    assert 1 - (1 - new_o[3].double()) ** 150 == pytest.approx(0.02, rel=1e-5)
    # D(n, x) for large n against the integral form (2/sqrt(pi)) int_0^inf 1 - (1 - x e^{-u^2})^n du.
    x = float(new_o[3])
    mpmath.mp.dps = 30
    integral = 2 / mpmath.sqrt(mpmath.pi) * mpmath.quad(lambda u: 1 - (1 - x * mpmath.e ** (-(u**2))) ** 150, [0, 3, mpmath.inf])
    got = relocation_denominator(torch.tensor([150]), torch.tensor([x], dtype=torch.float64)).item()
    assert got == pytest.approx(float(integral), rel=1e-9)


def test_sample_proportional_frequencies_and_zero_weights() -> None:
    w = torch.tensor([0.0, 1.0, 3.0, 0.0, 6.0])
    idx = sample_proportional(w, 20000, torch.Generator().manual_seed(3))
    freq = torch.bincount(idx, minlength=5).double() / 20000
    assert freq[0] == 0 and freq[3] == 0
    assert freq[[1, 2, 4]].tolist() == pytest.approx([0.1, 0.3, 0.6], abs=0.015)
    with pytest.raises(ValueError):
        sample_proportional(torch.zeros(3), 2)


# ------------------------------------------------------------------------------------------
# Relocation


@pytest.mark.parametrize("device", DEVICES)
def test_relocate_dead_moves_dead_onto_sources_of_same_instance(device: str) -> None:
    g = two_instance_scene(device)
    config = MCMCConfig()
    before = {name: getattr(g, name).detach().clone() for name in g.PARAM_NAMES}
    ids_before = g.instance_ids.clone()
    dead = torch.sigmoid(before["opacities"]) < config.min_opacity
    optimizers = adam_for(g)
    fake_train_step(g, optimizers)  # non-zero Adam moments
    before = {name: getattr(g, name).detach().clone() for name in g.PARAM_NAMES}
    params_before = {name: getattr(g, name) for name in g.PARAM_NAMES}

    n = relocate_dead(g, optimizers, config, torch.Generator(device=device).manual_seed(0))
    assert n == int(dead.sum()) == 30
    # Relocation is in place: the same Parameter objects stay in the optimisers.
    assert all(getattr(g, name) is params_before[name] for name in g.PARAM_NAMES)
    # Nothing is dead any more.
    assert (torch.sigmoid(g.opacities) >= config.min_opacity).all()

    # Every Gaussian's (id, canonical mean, colour) comes from an alive Gaussian of the same id.
    alive_ids, alive_means = ids_before[~dead], before["means"][~dead]
    alive_rgb = before["features_rgb"][~dead]
    sources = []
    for i in range(g.num):
        match = (alive_ids == g.instance_ids[i]) & (alive_means == g.means[i].detach()).all(dim=1)
        assert match.sum() == 1, f"Gaussian {i} has an (id, mean) pair no alive Gaussian had"
        j = torch.nonzero(match).item()
        assert torch.equal(alive_rgb[j], g.features_rgb[i].detach())
        sources.append(torch.nonzero(~dead).flatten()[j].item())
    sources = torch.tensor(sources, device=device)
    # Alive Gaussians stay where they were; each dead one got a copy of some alive one.
    alive_idx = torch.nonzero(~dead).flatten()
    assert torch.equal(sources[alive_idx], alive_idx)
    copied_from = sources[dead]
    assert (~dead[copied_from]).all()
    assert len(torch.unique(copied_from)) < len(copied_from)  # some groups have several copies
    # Sources received copies: each group (source + copies) carries the relocation opacity/scale.
    for s in torch.unique(copied_from).tolist():
        members = torch.nonzero(sources == s).flatten()
        count = len(members)
        o_old = torch.sigmoid(before["opacities"][s]).item()
        eo, es = paper_relocation(o_old, 1.0, count)
        for m in members.tolist():
            assert torch.sigmoid(g.opacities[m]).item() == pytest.approx(max(eo, config.min_opacity), rel=1e-5)
            ratio = torch.exp(g.scales[m].detach()) / torch.exp(before["scales"][s])
            assert ratio.tolist() == pytest.approx([es] * 3, rel=1e-4)
    # Untouched alive Gaussians keep their values exactly.
    untouched = torch.ones(g.num, dtype=torch.bool, device=device)
    untouched[dead] = False
    untouched[copied_from] = False
    for name in g.PARAM_NAMES:
        assert torch.equal(getattr(g, name).detach()[untouched], before[name][untouched])
    # Adam moments: zero on touched rows, unchanged elsewhere.
    for name in g.PARAM_NAMES:
        state = optimizers[name].state[getattr(g, name)]
        for key in ("exp_avg", "exp_avg_sq"):
            assert (state[key][~untouched] == 0).all()
            assert (state[key][untouched] != 0).any()
    fake_train_step(g, optimizers)  # training continues


def test_relocated_opacity_floor_is_alive() -> None:
    # One barely alive source shared by many dead ones: 1 - (1 - o)^(1/n) falls below min_opacity
    # and is floored so that no relocated Gaussian is dead again.
    g = make_gaussians([0.0051] + [0.0001] * 9, [3] * 10, torch.zeros(10, 3))
    config = MCMCConfig()
    assert relocate_dead(g, {}, config, torch.Generator().manual_seed(0)) == 9
    assert (torch.sigmoid(g.opacities) >= config.min_opacity).all()
    assert (g.instance_ids == 3).all()


def test_relocate_nothing_to_do() -> None:
    config = MCMCConfig()
    g = make_gaussians([0.5, 0.6], [0, 1], torch.zeros(2, 3))
    assert relocate_dead(g, {}, config) == 0
    g = make_gaussians([0.001, 0.002], [0, 1], torch.zeros(2, 3))
    before = g.means.detach().clone()
    assert relocate_dead(g, {}, config) == 0  # all dead: no source to draw from
    assert torch.equal(g.means.detach(), before)


# ------------------------------------------------------------------------------------------
# Growth


@pytest.mark.parametrize("device", DEVICES)
def test_add_new_appends_rows_to_params_ids_and_optimiser(device: str) -> None:
    g = two_instance_scene(device)
    config = MCMCConfig(cap_max=1000)
    optimizers = adam_for(g)
    fake_train_step(g, optimizers)
    n0 = g.num
    before = {name: getattr(g, name).detach().clone() for name in g.PARAM_NAMES}
    ids_before = g.instance_ids.clone()
    added = add_new(g, optimizers, 25, config, torch.Generator(device=device).manual_seed(0))
    assert added == 25 and g.num == n0 + 25 and g.instance_ids.shape == (n0 + 25,)
    for name in g.PARAM_NAMES:
        p = getattr(g, name)
        assert p.shape[0] == n0 + 25 and p.requires_grad
        opt = optimizers[name]
        assert opt.param_groups[0]["params"][0] is p
        state = opt.state[p]
        assert state["exp_avg"].shape == p.shape and state["exp_avg_sq"].shape == p.shape
        assert (state["exp_avg"][n0:] == 0).all() and (state["exp_avg_sq"][n0:] == 0).all()
        assert len(opt.state) == 1  # the old parameter's state is gone
    # New rows copy an existing Gaussian's (id, canonical mean).
    copied_from = []
    for i in range(n0, g.num):
        match = (ids_before == g.instance_ids[i]) & (before["means"] == g.means[i].detach()).all(dim=1)
        assert match.sum() == 1
        copied_from.append(torch.nonzero(match).item())
    # Each source and its copies share the source's opacity and scale by the relocation rule.
    copied_from = torch.tensor(copied_from, device=device)
    assert len(torch.unique(copied_from)) < 25  # some source drawn twice: groups larger than 2
    for s in torch.unique(copied_from).tolist():
        members = [s] + (n0 + torch.nonzero(copied_from == s).flatten()).tolist()
        eo, es = paper_relocation(torch.sigmoid(before["opacities"][s]).item(), 1.0, len(members))
        for m in members:
            assert torch.sigmoid(g.opacities[m]).item() == pytest.approx(max(eo, config.min_opacity), rel=1e-5)
            ratio = torch.exp(g.scales[m].detach()) / torch.exp(before["scales"][s])
            assert ratio.tolist() == pytest.approx([es] * 3, rel=1e-4)
    # Sampling in proportion to opacity never draws dead sources (opacity 0.001 vs >= 0.05) often;
    # their total weight is 30 * 0.001 out of ~30: a new row from a dead source would be a fluke.
    new_opacity = torch.sigmoid(g.opacities[n0:])
    assert (new_opacity >= config.min_opacity).all()
    # One Adam step works on the grown set.
    fake_train_step(g, optimizers)
    assert all(torch.isfinite(getattr(g, name)).all() for name in g.PARAM_NAMES)


def test_add_new_respects_cap_and_shared_optimizer() -> None:
    g = two_instance_scene()
    # One optimiser holding every parameter in separate groups (nerfstudio-like variations).
    opt = torch.optim.Adam([{"params": [getattr(g, n)], "lr": 1e-3} for n in g.PARAM_NAMES])
    optimizers = {n: opt for n in g.PARAM_NAMES}
    fake_train_step(g, {"all": opt})
    config = MCMCConfig(cap_max=g.num + 7)
    assert add_new(g, optimizers, 50, config, torch.Generator().manual_seed(0)) == 7
    assert g.num == 97
    assert add_new(g, optimizers, 50, config) == 0
    assert [grp["params"][0] for grp in opt.param_groups] == [getattr(g, n) for n in g.PARAM_NAMES]
    assert set(map(id, opt.state)) == {id(getattr(g, n)) for n in g.PARAM_NAMES}
    fake_train_step(g, {"all": opt})


def test_densifier_schedule_and_growth() -> None:
    g = two_instance_scene()
    optimizers = adam_for(g)
    densifier = MCMCDensifier(MCMCConfig(cap_max=100, refine_start_iter=200, refine_stop_iter=400, refine_every=100))
    assert [densifier.is_refine_step(s) for s in (100, 199, 200, 250, 300, 400)] == [False, False, True, False, True, False]
    counts = densifier.step(100, g, optimizers, lr_means=1e-4)
    assert counts.as_dict() == {"relocated": 0, "added": 0, "total": 90}
    counts = densifier.step(200, g, optimizers, lr_means=1e-4)
    assert counts.relocated == 30 and counts.added == 4 and counts.total == 94  # int(1.05 * 90) = 94
    counts = densifier.step(300, g, optimizers, lr_means=1e-4)
    assert counts.added == 4 and counts.total == 98  # int(1.05 * 94) = 98
    fake_train_step(g, optimizers)


def test_config_rejects_bad_values() -> None:
    with pytest.raises(IDSplatError, match="cap_max"):
        MCMCConfig(cap_max=0)
    with pytest.raises(IDSplatError, match="min_opacity"):
        MCMCConfig(min_opacity=1.5)


# ------------------------------------------------------------------------------------------
# Noise and regularisation


@pytest.mark.parametrize("device", DEVICES)
def test_noise_gated_by_opacity_and_shaped_by_covariance(device: str) -> None:
    n = 2000
    opacities = [0.9] * n + [0.001] * n
    g = make_gaussians(opacities, [0] * (2 * n), torch.zeros(2 * n, 3), device)
    with torch.no_grad():
        # Elongated along world x: scales (1, 0.1, 0.1), identity rotation.
        g.scales.copy_(torch.log(torch.tensor([1.0, 0.1, 0.1])).expand(2 * n, 3))
        g.quats.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(2 * n, 4))
    config = MCMCConfig()
    before = g.means.detach().clone()
    noise = inject_noise(g, 1e-4, config, torch.Generator(device=device).manual_seed(0))
    moved = g.means.detach() - before
    assert torch.allclose(moved, noise)
    assert moved[:n].abs().max().item() < 1e-20  # opaque: no noise
    transparent = moved[n:]
    # gate ~ sigmoid(100 * 0.004) = 0.599; noise = 5e5 * 1e-4 * gate * Sigma eta, Sigma = diag(1, .01, .01).
    gate = 1 / (1 + math.exp(-100 * (0.005 - 0.001)))
    expected_std = torch.tensor([1.0, 0.01, 0.01]) * 50 * gate
    assert (transparent.std(dim=0).cpu() / expected_std).tolist() == pytest.approx([1, 1, 1], abs=0.08)


def test_mcmc_regularisation_value_and_gradient() -> None:
    g = make_gaussians([0.2, 0.6], [0, 1], torch.zeros(2, 3))
    with torch.no_grad():
        g.scales.copy_(torch.log(torch.tensor([[0.1, 0.2, 0.3], [1.0, 2.0, 3.0]])))
    config = MCMCConfig()
    value = mcmc_regularisation(g, config)
    expected = 5e-3 * (0.2 + 0.6) / 2 + 1e-3 * (0.1 + 0.2 + 0.3 + 1 + 2 + 3) / 6
    assert value.item() == pytest.approx(expected, rel=1e-6)
    value.backward()
    # d/dlogit of mean(sigmoid) = o (1 - o) / N.
    assert g.opacities.grad.tolist() == pytest.approx([5e-3 * 0.2 * 0.8 / 2, 5e-3 * 0.6 * 0.4 / 2], rel=1e-5)
