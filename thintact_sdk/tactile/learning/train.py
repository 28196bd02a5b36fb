"""CycleGAN training of Real2Sim on unpaired real and simulated tactile images.

Least-squares GAN losses, cycle-consistency (weight 10) and identity (weight 5) terms, Adam
(2e-4, β = 0.5, 0.999) with the learning rate held for the first half of the iterations and
decayed linearly to zero over the second, as in Zhu et al. (2017). Differences, for a CPU and
a few dozen real images: small networks (:mod:`.networks`), mini-batches of random square
crops (the networks are fully convolutional and are applied to whole images afterwards) drawn
by a seeded generator, and no history pool of fakes (so a resumed run is bit-identical to an
uninterrupted one).

Everything needed to resume sits in ``checkpoint.pt`` (networks, optimisers, iteration,
both random states, loss history), written atomically every ``checkpoint_every`` iterations
and at the end; the product is ``generator.pt`` (real → sim only, see :mod:`.model_file`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.learning.model_file import save_generator, select_device
from thintact_sdk.tactile.learning.networks import PatchDiscriminator, ResnetGenerator
from thintact_sdk.tactile.learning.translate import to_tensor

CHECKPOINT_FORMAT = "thintact-real2sim-checkpoint/1"


@dataclass
class TrainConfig:
    """Hyper-parameters of one training run (stored in the checkpoint)."""

    iterations: int = 3000
    batch: int = 4
    crop: int = 64
    width: int = 8
    blocks: int = 3
    edge_kernel: int = 5
    lr: float = 2e-4
    cycle_weight: float = 10.0
    identity_weight: float = 5.0
    checkpoint_every: int = 100
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("iterations", "batch", "crop", "width", "blocks", "edge_kernel",
                     "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ThinTactError(f"real2sim training: {name} must be ≥ 1")
        if self.crop % 4:
            raise ThinTactError("real2sim training: crop must be a multiple of 4")
        if not self.lr > 0:
            raise ThinTactError("real2sim training: lr must be > 0")


@dataclass
class TrainResult:
    """What a finished (or resumed and finished) run produced."""

    generator_path: Path
    iterations: int
    seconds: float
    device: str
    history: list[dict[str, float]] = field(default_factory=list)


class CycleGAN(nn.Module):
    """Both generators (real→sim, sim→real) and both discriminators."""

    def __init__(self, width: int, blocks: int, edge_kernel: int) -> None:
        super().__init__()
        self.real_to_sim = ResnetGenerator(width, blocks, edge_kernel=edge_kernel)
        self.sim_to_real = ResnetGenerator(width, blocks, edge_kernel=edge_kernel)
        self.d_sim = PatchDiscriminator()
        self.d_real = PatchDiscriminator()


def _lr_factor(iteration: int, total: int) -> float:
    half = total // 2
    return 1.0 if iteration < half else max(0.0, 1.0 - (iteration - half) / max(1, total - half))


def _gan_loss(scores: torch.Tensor, target: float) -> torch.Tensor:
    return torch.mean((scores - target) ** 2)


class Real2SimTrainer:
    """Trains a CycleGAN between ``real`` and ``sim`` images and checkpoints into ``out_dir``.

    Parameters
    ----------
    real, sim
        ``P × H × W × 3`` and ``Q × H × W × 3`` float32 images in [0, 1] (H, W multiples of 4).
    out_dir
        Receives ``checkpoint.pt``, ``generator.pt`` and ``training.json``.
    config
        Hyper-parameters; a resumed run must use the same network shape.
    device
        ``auto`` (CUDA when present), ``cpu`` or ``cuda``.
    """

    def __init__(self, real: np.ndarray, sim: np.ndarray, out_dir: str | Path,
                 config: TrainConfig | None = None, device: str = "auto") -> None:
        self.config = config or TrainConfig()
        if real.shape[1:] != sim.shape[1:] or real.ndim != 4:
            raise ThinTactError(
                f"real and sim images must share H×W×3, got {real.shape[1:]} and {sim.shape[1:]}")
        if min(real.shape[1:3]) < self.config.crop:
            raise ThinTactError(
                f"images of {real.shape[1]}×{real.shape[2]} px are smaller than the "
                f"{self.config.crop} px training crop")
        self.device = select_device(device)
        self.real = to_tensor(real, self.device)
        self.sim = to_tensor(sim, self.device)
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(self.config.seed)
        self.model = CycleGAN(self.config.width, self.config.blocks, self.config.edge_kernel).to(self.device)
        m, lr = self.model, self.config.lr
        self.opt_g = torch.optim.Adam(
            list(m.real_to_sim.parameters()) + list(m.sim_to_real.parameters()), lr, (0.5, 0.999))
        self.opt_d = torch.optim.Adam(
            list(m.d_sim.parameters()) + list(m.d_real.parameters()), lr, (0.5, 0.999))
        self.rng = np.random.default_rng(self.config.seed)
        self.iteration = 0
        self.history: list[dict[str, float]] = []
        self.seconds = 0.0

    @property
    def checkpoint_path(self) -> Path:
        return self.out_dir / "checkpoint.pt"

    def resume(self) -> bool:
        """Load ``checkpoint.pt`` if there is one; True when it was loaded.

        The file is read with ``torch.load(weights_only=True)``: tensors, numbers, strings,
        dicts and lists only, never code (a checkpoint is a file a user may be handed).

        Raises
        ------
        ThinTactError
            Naming the file: unreadable, torn, foreign (pickled code included), another
            network shape, or fields of the wrong type.
        """
        p = self.checkpoint_path
        if not p.is_file():
            return False
        try:
            blob = torch.load(p, map_location=self.device, weights_only=True)
        except Exception as exc:  # a torn or foreign file; torch raises many unrelated types
            raise ThinTactError(f"{p}: unreadable checkpoint ({exc.__class__.__name__}); "
                                "remove it to start afresh") from None
        if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
            raise ThinTactError(f"{p}: not a {CHECKPOINT_FORMAT} file")
        saved = blob.get("config")
        if not isinstance(saved, dict):
            raise ThinTactError(f"{p}: checkpoint 'config' must be a dict")
        for key in ("width", "blocks", "edge_kernel", "batch", "crop", "seed"):
            if saved.get(key) != getattr(self.config, key):
                raise ThinTactError(
                    f"{p}: checkpoint has {key}={saved.get(key)}, this run asks for "
                    f"{getattr(self.config, key)}; use the same settings or another --out")
        try:
            self.model.load_state_dict(blob["model"])
            self.opt_g.load_state_dict(blob["opt_g"])
            self.opt_d.load_state_dict(blob["opt_d"])
            self.rng.bit_generator.state = blob["numpy_rng"]
            torch.set_rng_state(blob["torch_rng"])
            self.iteration = int(blob["iteration"])
            self.history = [dict(h) for h in blob["history"]]
            self.seconds = float(blob.get("seconds", 0.0))
        except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as exc:
            raise ThinTactError(f"{p}: damaged checkpoint ({exc.__class__.__name__}: {exc}); "
                                "remove it to start afresh") from None
        return True

    def save_checkpoint(self) -> None:
        """Write everything needed to resume, atomically."""
        tmp = self.checkpoint_path.with_name("checkpoint.pt.tmp")
        torch.save({
            "format": CHECKPOINT_FORMAT, "config": asdict(self.config),
            "iteration": self.iteration, "model": self.model.state_dict(),
            "opt_g": self.opt_g.state_dict(), "opt_d": self.opt_d.state_dict(),
            "numpy_rng": self.rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
            "history": self.history, "seconds": self.seconds,
        }, tmp)
        tmp.replace(self.checkpoint_path)

    def _crops(self, images: torch.Tensor) -> torch.Tensor:
        """``batch`` random ``crop × crop`` windows of random images (seeded)."""
        c, (h, w) = self.config.crop, images.shape[-2:]
        idx = self.rng.integers(0, len(images), self.config.batch)
        rows = self.rng.integers(0, h - c + 1, self.config.batch)
        cols = self.rng.integers(0, w - c + 1, self.config.batch)
        return torch.stack([images[i, :, r : r + c, q : q + c]
                            for i, r, q in zip(idx, rows, cols, strict=True)])

    def step(self) -> dict[str, float]:
        """One generator and one discriminator update on a fresh mini-batch."""
        cfg, m = self.config, self.model
        for opt in (self.opt_g, self.opt_d):
            for group in opt.param_groups:
                group["lr"] = cfg.lr * _lr_factor(self.iteration, cfg.iterations)
        real, sim = self._crops(self.real), self._crops(self.sim)
        fake_sim, fake_real = m.real_to_sim(real), m.sim_to_real(sim)
        for d in (m.d_sim, m.d_real):
            d.requires_grad_(False)
        adv = _gan_loss(m.d_sim(fake_sim), 1.0) + _gan_loss(m.d_real(fake_real), 1.0)
        cycle = (torch.mean(torch.abs(m.sim_to_real(fake_sim) - real))
                 + torch.mean(torch.abs(m.real_to_sim(fake_real) - sim)))
        ident = (torch.mean(torch.abs(m.real_to_sim(sim) - sim))
                 + torch.mean(torch.abs(m.sim_to_real(real) - real)))
        g_loss = adv + cfg.cycle_weight * cycle + cfg.identity_weight * ident
        if not torch.isfinite(g_loss):
            raise ThinTactError(
                f"real2sim training diverged at iteration {self.iteration + 1} (non-finite "
                f"loss); the last checkpoint is at iteration {self.iteration - self.iteration % cfg.checkpoint_every}")
        self.opt_g.zero_grad(set_to_none=True)
        g_loss.backward()
        self.opt_g.step()
        for d in (m.d_sim, m.d_real):
            d.requires_grad_(True)
        d_loss = 0.5 * (_gan_loss(m.d_sim(sim), 1.0) + _gan_loss(m.d_sim(fake_sim.detach()), 0.0)
                        + _gan_loss(m.d_real(real), 1.0)
                        + _gan_loss(m.d_real(fake_real.detach()), 0.0))
        self.opt_d.zero_grad(set_to_none=True)
        d_loss.backward()
        self.opt_d.step()
        self.iteration += 1
        return {"iteration": float(self.iteration), "g_adv": adv.item(), "cycle": cycle.item(),
                "identity": ident.item(), "d": d_loss.item()}

    def run(self, on_step: Callable[[int, dict[str, float]], None] | None = None,
            meta: dict[str, Any] | None = None) -> TrainResult:
        """Train up to ``config.iterations`` (from wherever a resume left off), checkpointing
        on the way, then write ``generator.pt`` and ``training.json``."""
        cfg = self.config
        t0 = time.perf_counter() - self.seconds
        while self.iteration < cfg.iterations:
            losses = self.step()
            if self.iteration % 10 == 0 or self.iteration == cfg.iterations:
                self.history.append(losses)
            self.seconds = time.perf_counter() - t0
            if self.iteration % cfg.checkpoint_every == 0 or self.iteration == cfg.iterations:
                self.save_checkpoint()
            if on_step is not None:
                on_step(self.iteration, losses)
        info = {"config": asdict(cfg), "iterations": self.iteration, "seconds": self.seconds,
                "device": str(self.device), "real_images": len(self.real),
                "sim_images": len(self.sim), **(meta or {})}
        path = save_generator(self.out_dir / "generator.pt", self.model.real_to_sim,
                              {"width": cfg.width, "blocks": cfg.blocks,
                               "edge_kernel": cfg.edge_kernel}, info)
        (self.out_dir / "training.json").write_text(
            json.dumps({**info, "history": self.history}, indent=1) + "\n")
        return TrainResult(path, self.iteration, self.seconds, str(self.device), self.history)


def train_from_pack(
    real_pack: str | Path,
    out_dir: str | Path,
    train: list[int] | None = None,
    iterations: int = 3000,
    sim_presses: int = 48,
    mm_per_px: float = 0.1245,
    ball_radius_mm: float = 2.0,
    sim_model: str | Path | None = None,
    device: str = "auto",
    seed: int = 0,
    fresh: bool = False,
    on_step: Callable[[int, int, dict[str, float], float], None] | None = None,
) -> tuple[TrainResult, int, list[int]]:
    """``thintact real2sim train``: Real2Sim between a press pack's ``train`` presses (default
    the even ones) plus its no-contact frame and the sim domain
    (:func:`~thintact_sdk.tactile.learning.domains.sim_domain`: the nominal tactile simulation,
    or the one ``diagnose-tactile`` fitted when ``sim_model`` names its ``fitted_tactile.yaml``),
    resuming from ``out_dir``'s checkpoint unless ``fresh``.

    ``on_step(iteration, total, losses, seconds)`` is called after every iteration.

    Returns
    -------
    (result, resumed_at, test)
        The finished run, the iteration it resumed from (0 when fresh) and the presses kept
        unseen (stored in the generator file with the training presses).
    """
    from thintact_sdk.tactile.calibration.gelsight_eval import split_presses
    from thintact_sdk.tactile.learning.domains import RealPresses
    from thintact_sdk.tactile.learning.fitted_domain import fitted_section, sim_domain

    real = RealPresses.from_pack(real_pack)
    train, test = split_presses(len(real.images), train)
    if not train or max(train) >= len(real.images) or min(train) < 0:
        raise ThinTactError(f"--train: press indices must lie in 0..{len(real.images) - 1}")
    sim = sim_domain(real, sim_presses, ball_radius_mm, mm_per_px, seed, sim_model)
    section = None if sim_model is None else fitted_section(sim_model, real.reference.shape[:2])
    trainer = Real2SimTrainer(np.concatenate([real.subset(train), real.reference[None]]), sim,
                              out_dir, TrainConfig(iterations=iterations, seed=seed), device)
    if fresh:
        trainer.checkpoint_path.unlink(missing_ok=True)
    resumed_at = trainer.iteration if not fresh and trainer.resume() else 0
    rows, cols = real.reference.shape[:2]
    meta = {"real_source": str(real_pack), "train_presses": train, "test_presses": test,
            "real_shape": [rows, cols, 3], "mm_per_px": mm_per_px,
            "ball_radius_mm": ball_radius_mm, "sim_presses": sim_presses,
            "sim_model": None if sim_model is None else str(sim_model),
            "sim_model_section": section}

    def step(i: int, losses: dict[str, float]) -> None:
        if on_step is not None:
            on_step(i, iterations, losses, trainer.seconds)

    return trainer.run(step, meta), resumed_at, test
