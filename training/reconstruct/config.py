"""Reconstruction settings: ``ReconstructConfig`` (with its density control, ``DensifyConfig``), the presets, and
the rules a value must meet (``validate``). Plain Python, no torch: the CLI's ``--help`` reads the presets from here.

The trainer (training/reconstruct/trainer.py) reads the config afresh at every step; ``FIXED_AT_START`` names the
fields only construction may set, which a live update refuses.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

from training.raster.constants import BACKENDS

PRESETS = ("quick", "standard", "paper")
BACKGROUNDS = ("black", "white", "random")
DEPTH_SOURCES = ("sfm", "mono", "none")
DEVICES = ("auto", "cpu", "cuda")
# Settings that shape the run when the trainer is built (the scene's resolution, the depth targets, the initial model,
# the device, the background the photos are composited over): update_config refuses them rather than ignore them.
FIXED_AT_START = ("preset", "downscale", "max_side", "depth", "mono_depth_model", "device", "background",
                  "random_init_points", "seed")


@dataclass
class DensifyConfig:
    start: int = 500
    stop: int = 15000
    interval: int = 100
    grad_threshold: float = 0.0002
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    prune_world: float = 0.1
    prune_screen: float = 0.15  # of the image's long side; 0 = no screen-size pruning
    reset_every: int = 3000
    reset_opacity: float = 0.01
    max_gaussians: int | None = None
    enabled: bool = True


@dataclass
class ReconstructConfig:
    preset: str = "standard"
    iterations: int = 7000
    # The training resolution, applied by whoever loads the scene (training/reconstruct/resolution.py); the trainer
    # takes the scene as given. max_side (the longest image side at most, in pixels) wins when set; downscale is
    # the whole factor used when max_side is None (and the factor max_side resolved to, once resolved).
    downscale: int = 4
    max_side: int | None = 1000
    sh_degree: int = 3
    sh_interval: int = 1000
    lr_means_init: float = 1.6e-4  # x scene extent
    lr_means_final: float = 1.6e-6  # x scene extent
    lr_sh0: float = 2.5e-3
    lr_shN: float = 2.5e-3 / 20
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lambda_dssim: float = 0.2
    # the paper's regularizers
    use_shape: bool = True
    lambda_shape: float = 10.0
    lambda_s: float = 3.5
    use_size: bool = True
    lambda_size: float = 1.0
    beta1: float = 0.1
    beta2: float = 0.001
    depth: str = "sfm"  # "sfm" | "mono" | "none": where depth targets come from (fixed at construction)
    use_depth: bool = True  # switches the depth term on and off between steps
    lambda_depth_start: float = 1.0
    lambda_depth_end: float = 0.01
    mono_depth_model: str | None = None
    # everything else
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    background: str = "black"
    backend: str = "auto"
    device: str = "auto"  # "auto" (cuda when available) | "cpu" | "cuda"
    random_init_points: int = 50_000  # when the scene has no SfM points
    snapshot_every: int = 100
    seed: int = 0
    # the run's held-out scoring (training/reconstruct/pipeline.py; the trainer's step never reads these): the test
    # views scored every eval_every iterations (None: a tenth of the run; 0: never), and with stop_when_flat N > 0
    # the run ended once densification has stopped and their PSNR has not risen by 0.05 dB for N iterations
    eval_every: int | None = None
    stop_when_flat: int = 0

    @classmethod
    def from_preset(cls, name: str, **overrides) -> "ReconstructConfig":
        """``quick`` (minutes on 2 CPU cores, long side ~400 px), ``standard`` (~1000 px), or ``paper`` (3DGS's 30k
        schedule at full resolution, for a GPU)."""
        if name == "quick":
            # 5000 iterations: at ~400 px the fox needs them to match what 3000 gave at 236 px (docs/reconstruction.md)
            cfg = cls(preset="quick", iterations=5000, downscale=8, max_side=400, sh_interval=500,
                      random_init_points=5000,
                      densify=DensifyConfig(start=250, stop=2500, interval=167, reset_every=1500,
                                            max_gaussians=60_000))
        elif name == "standard":
            cfg = cls(preset="standard", iterations=7000, downscale=4, max_side=1000, sh_interval=1000,
                      random_init_points=30_000,
                      densify=DensifyConfig(start=500, stop=3500, interval=100, reset_every=3000,
                                            max_gaussians=300_000))
        elif name == "paper":
            cfg = cls(preset="paper", iterations=30_000, downscale=1, max_side=None, sh_interval=1000,
                      random_init_points=100_000,
                      densify=DensifyConfig(start=500, stop=15_000, interval=100, reset_every=3000))
        else:
            raise ValueError(f"unknown preset {name!r}; expected one of {', '.join(PRESETS)}")
        return replace(cfg, **overrides)

    def with_iterations(self, iterations: int) -> "ReconstructConfig":
        """A copy that runs ``iterations`` steps, with the density-control window and interval, the opacity reset
        period and the SH interval stretched by iterations / self.iterations, so a shorter or longer run densifies,
        resets and raises its SH degree at the same fractions of the run as the preset."""
        cfg = replace(self, densify=replace(self.densify), iterations=int(iterations))
        if cfg.iterations == self.iterations or self.iterations < 1:
            return cfg
        f = cfg.iterations / self.iterations
        d = cfg.densify
        d.start = max(1, int(round(d.start * f)))
        d.stop = max(d.start + 1, int(round(d.stop * f)))
        d.interval = max(1, int(round(d.interval * f)))
        d.reset_every = max(1, int(round(d.reset_every * f))) if d.reset_every > 0 else 0
        cfg.sh_interval = max(1, int(round(cfg.sh_interval * f)))
        return cfg

    def validate(self) -> None:
        """ValueError naming the first setting out of its range."""
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; expected one of {', '.join(PRESETS)}")
        if self.depth not in DEPTH_SOURCES:
            raise ValueError(f"unknown depth {self.depth!r}; expected one of {', '.join(DEPTH_SOURCES)}")
        if self.background not in BACKGROUNDS:
            raise ValueError(f"unknown background {self.background!r}; expected one of {', '.join(BACKGROUNDS)}")
        if self.backend not in BACKENDS:
            raise ValueError(f"unknown backend {self.backend!r}; expected one of {', '.join(BACKENDS)}")
        if self.device not in DEVICES and not str(self.device).startswith("cuda:"):
            raise ValueError(f"unknown device {self.device!r}; expected one of {', '.join(DEVICES)}")
        d = self.densify
        checks = [("iterations", self.iterations >= 1, "at least 1"), ("downscale", self.downscale >= 1, "at least 1"),
                  ("max_side", self.max_side is None or self.max_side >= 16, "at least 16 (or None)"),
                  ("sh_degree", 0 <= self.sh_degree <= 3, "0..3"), ("sh_interval", self.sh_interval >= 1, "at least 1"),
                  *[(n, getattr(self, n) > 0, "positive") for n in
                    ("lr_means_init", "lr_means_final", "lr_sh0", "lr_shN", "lr_opacity", "lr_scales", "lr_quats")],
                  ("lambda_dssim", 0 <= self.lambda_dssim <= 1, "in [0, 1]"),
                  *[(n, getattr(self, n) >= 0, "at least 0") for n in
                    ("lambda_shape", "lambda_s", "lambda_size", "beta1", "beta2", "lambda_depth_start",
                     "lambda_depth_end")],
                  ("random_init_points", self.random_init_points >= 1, "at least 1"),
                  ("snapshot_every", self.snapshot_every >= 0, "at least 0"),
                  ("eval_every", self.eval_every is None or self.eval_every >= 0, "at least 0 (0: never; or None)"),
                  ("stop_when_flat", self.stop_when_flat >= 0, "at least 0 (0: off)"),
                  ("densify.interval", d.interval >= 1, "at least 1"),
                  ("densify.grad_threshold", d.grad_threshold > 0, "positive"),
                  ("densify.prune_screen", d.prune_screen >= 0, "at least 0 (0: off)"),
                  ("densify.reset_every", d.reset_every >= 0, "at least 0 (0: never)"),
                  ("densify.max_gaussians", d.max_gaussians is None or d.max_gaussians >= 1, "at least 1")]
        for name, ok, rule in checks:
            if not ok:
                value = getattr(d, name.split(".")[1]) if name.startswith("densify.") else getattr(self, name)
                raise ValueError(f"{name} must be {rule}, got {value!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "ReconstructConfig":
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        dens = d.pop("densify", {}) or {}
        dknown = {f.name for f in fields(DensifyConfig)}
        return cls(**d, densify=DensifyConfig(**{k: v for k, v in dens.items() if k in dknown}))
