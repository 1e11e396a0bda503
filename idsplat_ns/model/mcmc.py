"""MCMC densification of Kheradmand et al., "3D Gaussian Splatting as Markov Chain Monte Carlo" (2024).

Pure torch, CPU or GPU. Every ``refine_every`` steps within ``[refine_start_iter, refine_stop_iter)``
the Gaussians whose opacity fell below ``min_opacity`` are moved onto alive Gaussians sampled in
proportion to opacity (:func:`relocate_dead`), then the set grows by ``growth_rate`` up to
``cap_max`` the same way (:func:`add_new`); every step the means get noise shaped by each
Gaussian's covariance and gated to the transparent ones (:func:`inject_noise`). The loss gets the
opacity and scale regularisers (:func:`mcmc_regularisation`).

Instances: a copy takes the source's ``instance_ids`` entry together with its parameters. Means of
instance Gaussians are canonical coordinates of their instance, so copying the pair (id, canonical
mean) keeps the copy on the source's object; a Gaussian never changes between an instance and the
background (or another instance) without its coordinates following. Noise is added in canonical
coordinates, which is the same as in world coordinates since the instance poses are rigid.

Optimisers: parameters are found in the optimisers by identity (the dict keys are not relied on);
Adam moments of rows that relocation touches are zeroed, rows appended by growth get zero
moments, and the optimisers' ``param_groups`` are pointed at the new ``nn.Parameter`` objects.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass

import torch
from torch import Tensor, nn

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.mcmc_relocation import relocation_update, sample_proportional
from idsplat_ns.render.projection import covariance_3d
from idsplat_ns.ranges import AT_LEAST_ONE, UNIT, Range, bounded

# Upper bound for relocated opacities: the largest float32 value below 1 (finite logit).
_MAX_OPACITY = 1.0 - 2.0**-24


@dataclass
class MCMCConfig:
    """Hyperparameters of MCMC densification (defaults: gsplat 1.4.0's MCMCStrategy and the paper)."""

    cap_max: int = bounded(10_000_000, AT_LEAST_ONE)
    """Most Gaussians growth may reach (the paper: 10M; pass a cap that follows the scene's size)."""
    noise_lr: float = 5e5
    """Noise scale, multiplied by the current learning rate of the means."""
    refine_start_iter: int = 500
    """First step at which relocation and growth may run."""
    refine_stop_iter: int = 25_000
    """Relocation and growth run at steps before this one (noise continues after it)."""
    refine_every: int = bounded(100, AT_LEAST_ONE)
    """Relocation and growth run at steps that are multiples of this."""
    min_opacity: float = bounded(0.005, Range(0, 1, high_open=True))
    """Gaussians with a lower opacity are dead and get relocated; relocated opacities are floored here."""
    growth_rate: float = 0.05
    """Fraction by which the number of Gaussians grows at each refinement step (until cap_max)."""
    opacity_reg: float = 5e-3
    """Weight of the opacity regulariser (mean activated opacity)."""
    scale_reg: float = 1e-3
    """Weight of the scale regulariser (mean activated scale)."""
    noise_gate_opacity: float = bounded(0.005, UNIT)
    """Opacity at which the noise gate is one half: sigmoid(-k (o - this))."""
    noise_gate_sharpness: float = 100.0
    """Slope k of the noise gate: noise fades out for Gaussians more opaque than the gate opacity."""

    def __post_init__(self) -> None:
        if self.cap_max < 1:
            raise IDSplatError(f"MCMCConfig.cap_max must be >= 1, got {self.cap_max}; pass a positive cap")
        if self.refine_every < 1:
            raise IDSplatError(f"MCMCConfig.refine_every must be >= 1, got {self.refine_every}")
        if not 0.0 < self.min_opacity < 1.0:
            raise IDSplatError(f"MCMCConfig.min_opacity must be in (0, 1), got {self.min_opacity}")
        if self.growth_rate < 0.0:
            raise IDSplatError(f"MCMCConfig.growth_rate must be >= 0, got {self.growth_rate}")


@dataclass(frozen=True)
class MCMCStepCounts:
    """What one :meth:`MCMCDensifier.step` did (for logging)."""

    relocated: int  # dead Gaussians moved onto alive ones
    added: int  # Gaussians appended by growth
    total: int  # Gaussians after the step

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


# --------------------------------------------------------------------------------------------
# Optimiser bookkeeping


def _distinct(optimizers: dict[str, torch.optim.Optimizer]) -> list[torch.optim.Optimizer]:
    seen: dict[int, torch.optim.Optimizer] = {}
    for opt in optimizers.values():
        seen.setdefault(id(opt), opt)
    return list(seen.values())


def _is_row_state(value: object, param: Tensor) -> bool:
    """Per-element optimiser state (Adam's exp_avg, exp_avg_sq, ...), as opposed to ``step``."""
    return isinstance(value, Tensor) and value.shape == param.shape


def _owners(optimizers: Iterable[torch.optim.Optimizer], param: Tensor) -> list[tuple[torch.optim.Optimizer, dict, int]]:
    """(optimizer, param group, position) of every slot holding ``param`` (by identity)."""
    slots = []
    for opt in optimizers:
        for group in opt.param_groups:
            for i, p in enumerate(group["params"]):
                if p is param:
                    slots.append((opt, group, i))
    return slots


def _zero_state_rows_(optimizers: list[torch.optim.Optimizer], param: Tensor, rows: Tensor) -> None:
    for opt, _, _ in _owners(optimizers, param):
        for value in opt.state.get(param, {}).values():
            if _is_row_state(value, param):
                value[rows] = 0


def _replace_param(
    optimizers: list[torch.optim.Optimizer],
    old: nn.Parameter,
    new: nn.Parameter,
    edit_state: Callable[[Tensor], Tensor],  # maps a [N, ...] state tensor to the new rows
) -> None:
    for opt, group, i in _owners(optimizers, old):
        group["params"][i] = new
        state = opt.state.pop(old, None)
        if state is not None:
            opt.state[new] = {k: edit_state(v) if _is_row_state(v, old) else v for k, v in state.items()}


# --------------------------------------------------------------------------------------------
# Relocation and growth


def _opacity_logits(opacities: Tensor, min_opacity: float) -> Tensor:
    """Logits of ``opacities`` [M] clamped to [min_opacity, 1); their sigmoid is >= min_opacity."""
    logits = torch.logit(opacities.to(torch.float64).clamp(min_opacity, _MAX_OPACITY)).to(opacities.dtype)
    # The cast to float32 may round the floor's logit down; step it up until its sigmoid, computed
    # as the dead test computes it, is not below min_opacity.
    floor = torch.logit(torch.tensor(min_opacity, dtype=torch.float64)).to(opacities.dtype).to(opacities.device)
    while bool(torch.sigmoid(floor) < min_opacity):
        floor = torch.nextafter(floor, torch.full_like(floor, float("inf")))
    return torch.maximum(logits, floor)


def _share_sources_(gaussians: GaussianSet, sources: Tensor, min_opacity: float) -> Tensor:
    """Give every drawn source (``sources`` [K], repeats allowed) the relocation opacity and scale
    for its group of (copies + itself); returns the distinct sources."""
    unique, copies = torch.unique(sources, return_counts=True)
    opacities = torch.sigmoid(gaussians.opacities.data[unique])
    scales = torch.exp(gaussians.scales.data[unique])
    new_opacities, new_scales = relocation_update(opacities, scales, copies + 1)
    gaussians.opacities.data[unique] = _opacity_logits(new_opacities, min_opacity)
    gaussians.scales.data[unique] = torch.log(new_scales)
    return unique


def dead_mask(gaussians: GaussianSet, config: MCMCConfig) -> Tensor:
    """[N] bool: Gaussians whose opacity is below ``config.min_opacity``."""
    return torch.sigmoid(gaussians.opacities.detach()) < config.min_opacity


@torch.no_grad()
def relocate_dead(
    gaussians: GaussianSet,
    optimizers: dict[str, torch.optim.Optimizer],
    config: MCMCConfig,
    generator: torch.Generator | None = None,
) -> int:
    """Move dead Gaussians (opacity < min_opacity) onto alive ones drawn in proportion to opacity.

    Each dead Gaussian takes all parameters and the instance id of its drawn source; the source and
    its copies get the relocation opacity and scale; optimiser moments of every touched row are
    zeroed. ``generator`` must live on the Gaussians' device. Returns the number relocated (0 when
    nothing is dead or nothing is alive).
    """
    dead = dead_mask(gaussians, config)
    dead_idx = torch.nonzero(dead).flatten()
    alive_idx = torch.nonzero(~dead).flatten()
    if len(dead_idx) == 0 or len(alive_idx) == 0:
        return 0
    weights = torch.sigmoid(gaussians.opacities.data[alive_idx])
    sources = alive_idx[sample_proportional(weights, len(dead_idx), generator)]
    unique_sources = _share_sources_(gaussians, sources, config.min_opacity)
    for name in gaussians.PARAM_NAMES:
        p = getattr(gaussians, name)
        p.data[dead_idx] = p.data[sources]
    gaussians.instance_ids[dead_idx] = gaussians.instance_ids[sources]
    touched = torch.cat([dead_idx, unique_sources])
    opts = _distinct(optimizers)
    for name in gaussians.PARAM_NAMES:
        _zero_state_rows_(opts, getattr(gaussians, name), touched)
    return len(dead_idx)


@torch.no_grad()
def add_new(
    gaussians: GaussianSet,
    optimizers: dict[str, torch.optim.Optimizer],
    num: int,
    config: MCMCConfig,
    generator: torch.Generator | None = None,
) -> int:
    """Append up to ``num`` Gaussians (never past ``config.cap_max``), copies of existing ones drawn
    in proportion to opacity; sources and copies get the relocation opacity and scale.

    Every parameter becomes a new ``nn.Parameter`` (the optimisers are re-pointed to it, with zero
    moments for the new rows) and ``instance_ids`` grows with the sources' ids. ``generator`` must
    live on the Gaussians' device. Returns the number added.
    """
    num = min(int(num), config.cap_max - gaussians.num)
    if num <= 0 or gaussians.num == 0:
        return 0
    weights = torch.sigmoid(gaussians.opacities.data)
    sources = sample_proportional(weights, num, generator)
    _share_sources_(gaussians, sources, config.min_opacity)
    opts = _distinct(optimizers)

    def append_zero_rows(value: Tensor) -> Tensor:
        return torch.cat([value, value.new_zeros((num,) + tuple(value.shape[1:]))])

    for name in gaussians.PARAM_NAMES:
        old = getattr(gaussians, name)
        new = nn.Parameter(torch.cat([old.data, old.data[sources]]), requires_grad=old.requires_grad)
        _replace_param(opts, old, new, append_zero_rows)
        setattr(gaussians, name, new)
    gaussians.instance_ids = torch.cat([gaussians.instance_ids, gaussians.instance_ids[sources]])
    return num


# --------------------------------------------------------------------------------------------
# Noise and regularisation


@torch.no_grad()
def inject_noise(
    gaussians: GaussianSet,
    lr_means: float,
    config: MCMCConfig,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Add ``noise_lr * lr_means * gate(o) * Sigma @ eta`` to the means (eta ~ N(0, I)), in place.

    ``gate(o) = sigmoid(-k (o - noise_gate_opacity))`` is ~1 for transparent Gaussians and ~0 for
    opaque ones; ``Sigma`` is each Gaussian's covariance, so the noise follows its shape. Returns the
    noise added, [N, 3].
    """
    means = gaussians.means
    opacities = torch.sigmoid(gaussians.opacities.data)
    gate = torch.sigmoid(-config.noise_gate_sharpness * (opacities - config.noise_gate_opacity))
    covariances = covariance_3d(gaussians.quats.data, torch.exp(gaussians.scales.data))  # [N, 3, 3]
    eta = torch.randn(means.shape, generator=generator, dtype=means.dtype, device=means.device)
    eta = eta * (gate * (config.noise_lr * lr_means))[:, None]
    noise = torch.einsum("nij,nj->ni", covariances, eta)
    means.data.add_(noise)
    return noise


def mcmc_regularisation(gaussians: GaussianSet, config: MCMCConfig) -> Tensor:
    """``opacity_reg * mean(sigmoid(o)) + scale_reg * mean(exp(scales))``, differentiable (scalar)."""
    if gaussians.num == 0:
        return gaussians.opacities.sum() * 0.0
    opacity_term = torch.sigmoid(gaussians.opacities).mean()
    scale_term = torch.exp(gaussians.scales).mean()
    return config.opacity_reg * opacity_term + config.scale_reg * scale_term


# --------------------------------------------------------------------------------------------
# Schedule


class MCMCDensifier:
    """Applies the MCMC schedule after each optimiser step.

    Call :meth:`step` after ``optimizer.step()`` (and before the next forward pass): it relocates
    and grows at refinement steps and injects noise at every step. Random draws come from a
    generator seeded with ``seed`` on the Gaussians' device, so runs repeat.
    """

    def __init__(self, config: MCMCConfig, seed: int = 0) -> None:
        self.config = config
        self.seed = seed
        self._generator: torch.Generator | None = None

    def generator(self, device: torch.device) -> torch.Generator:
        """The densifier's generator on ``device`` (created on first use)."""
        device = torch.device(device)
        if self._generator is None or self._generator.device.type != device.type:
            self._generator = torch.Generator(device=device).manual_seed(self.seed)
        return self._generator

    @property
    def has_generator(self) -> bool:
        """Whether a draw has been made (the generator exists)."""
        return self._generator is not None

    def generator_state(self) -> torch.Tensor:
        """The generator's state (a CPU byte tensor), for a checkpoint."""
        assert self._generator is not None, "no generator yet: nothing drawn"
        return self._generator.get_state()

    def set_generator_state(self, state: torch.Tensor, device: torch.device | str) -> None:
        """Continue the draws of a checkpoint's generator on ``device``."""
        self.generator(device).set_state(state)

    def is_refine_step(self, step: int) -> bool:
        """Whether ``step`` relocates and grows."""
        c = self.config
        return c.refine_start_iter <= step < c.refine_stop_iter and step % c.refine_every == 0

    def growth_target(self, num: int) -> int:
        """How many Gaussians to add to a set of ``num`` at a refinement step."""
        return max(0, min(self.config.cap_max, int((1.0 + self.config.growth_rate) * num)) - num)

    def step(
        self,
        step: int,
        gaussians: GaussianSet,
        optimizers: dict[str, torch.optim.Optimizer],
        lr_means: float,
    ) -> MCMCStepCounts:
        """Relocate + grow (at refinement steps), then inject noise; returns what was done."""
        gen = self.generator(gaussians.means.device)
        relocated = added = 0
        if self.is_refine_step(step):
            relocated = relocate_dead(gaussians, optimizers, self.config, gen)
            added = add_new(gaussians, optimizers, self.growth_target(gaussians.num), self.config, gen)
        inject_noise(gaussians, lr_means, self.config, gen)
        return MCMCStepCounts(relocated=relocated, added=added, total=gaussians.num)
