"""The viewer's runs: starting a reconstruction, a stylization or both in the live session, the stylization settings
the panels edit (live where the running stylizer accepts them), the region it may change, and the view order it
follows. Mixed into ``ViewerApp``; every method runs on the UI thread."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def next_run_dir(out: Path, name: str = "stylized") -> Path:
    """``out/stylized`` for the first stylization, then ``stylized_2``, ``stylized_3``...: each run keeps its own
    output, and none overwrites another (also across sessions writing to the same folder)."""
    candidate, n = out / name, 1
    while candidate.exists():
        n += 1
        candidate = out / f"{name}_{n}"
    return candidate


class RunsMixin:
    def out_dir(self) -> Path:
        return Path(self.paths.out)

    def record_saved(self, stage: str, path: str) -> None:
        """A stage saved its model: a reconstruction becomes the model later stylizations start from; a
        stylization is listed as a run (and starts the next one only when the user asks to continue)."""
        if stage == "stylize":
            self.training.runs.append(Path(path))
        else:
            self.training.base_model = path
            self.paths.model = path
            self.colour.stylized_from = path  # a stylization started from it offers it as the original
        self.say(f"saved {path}")

    def start_reconstruction(self, then_stylize: bool = False) -> None:
        from app.viewer.stages import reconstruct_stage, stylize_stage

        if not self.paths.data:
            raise ValueError("open a dataset first (COLMAP folder or transforms.json)")
        overrides = {} if self.training.recon_iters is None else {"iterations": int(self.training.recon_iters)}
        # each run in a folder of its own (reconstruction, reconstruction_2...): a later run never overwrites a model
        # that a project or a stylization refers to
        stages = [reconstruct_stage(self.paths.data, next_run_dir(self.out_dir(), "reconstruction"),
                                    preset=self.training.preset, downscale=self.training.downscale, **overrides)]
        if then_stylize:
            if self.style_image is None:
                raise ValueError("open a painting first")
            stages.append(stylize_stage(self.paths.data, self.paths.style, next_run_dir(self.out_dir()),
                                        config=self._stylize_config_copy()))
        self.original = None
        self.error = ""
        self.session.start(stages)

    def start_stylization(self) -> None:
        from app.viewer.stages import stylize_stage

        if not self.paths.data:
            raise ValueError("open the dataset the model was reconstructed from")
        if self.style_image is None:
            raise ValueError("open a painting first")
        # from the model as opened or reconstructed, not the last stylized output (a run on top of a run would
        # compound the style), unless the user asks to continue the last run
        if self.training.continue_last_run and self.training.runs:
            model = str(self.training.runs[-1])
        else:
            model = self.training.base_model or self.paths.model or None
        if model is None:
            raise ValueError("open a model (PLY) or reconstruct first")
        run = next_run_dir(self.out_dir())
        if self.edited() and not (self.training.continue_last_run and self.training.runs):
            from training.model.ply_io import write_ply

            # the stylization starts from what the user sees: the model after the deletes and crops, kept in the
            # run's own folder (it is that run's original, for style strength; a later run writes its own)
            model = run / "edited_model.ply"
            model.parent.mkdir(parents=True, exist_ok=True)
            write_ply(model, self.edited_gaussians())
        from app.viewer.world_edit import in_file_frame

        self.original = in_file_frame(self, self.static_model)  # the run works in the file's (dataset's) frame
        self.colour.stylized_from = str(model)  # the Colour panel offers it as the result's original
        self.error = ""
        self.session.start([stylize_stage(self.paths.data, self.paths.style, run,
                                          config=self._stylize_config_copy(), model=model,
                                          mask=self.region_mask())])

    def region_mask(self) -> np.ndarray | None:
        """The Gaussians a stylization may change, over the edited model (None: all)."""
        if self.edit.region == "all" or self.editor is None:
            return None
        return self.editor.selected.copy() if self.edit.region == "selection" else ~self.editor.selected

    def set_style_region(self, region: str) -> None:
        """Which Gaussians the stylization changes; a running stylizer takes it at its next step."""
        self.edit.region = region
        trainer = self.session.trainer
        if self._stage == "stylize" and self.session.running and trainer is not None and hasattr(trainer, "set_mask"):
            mask = self.region_mask()

            def apply(t):
                if mask is not None and len(mask) != len(t.gaussians):
                    raise ValueError("the selection belongs to another model than the one being stylized")
                t.set_mask(mask)

            self.submit_to_trainer("stylize region", apply)

    def _stylize_config_copy(self):
        from dataclasses import replace

        return replace(self.training.stylize)

    def set_stylize(self, **changes: Any) -> None:
        """A slider moved: to the running stylizer (at its next step), and into the config of the next run."""
        from dataclasses import replace

        trainer = self.session.trainer
        if self._stage == "stylize" and self.session.running and trainer is not None:
            refusal = self.session.update_config(**changes)
            if refusal:
                self.fail(refusal)
                return
        candidate = replace(self.training.stylize, **changes)
        try:
            candidate.validate()
        except ValueError as exc:
            self.fail(str(exc))
            return
        self.training.stylize = candidate
        if any(k in changes for k in ("view_order", "virtual_views", "seed")):
            self.order_preview = None
            self.update_overlays()

    def trajectory(self) -> list[tuple[int, np.ndarray, bool]]:
        """(source camera index, centre, is virtual) in optimisation order: the running stylizer's, or the order
        the next stylization would follow."""
        trainer = self.session.trainer
        if self._stage == "stylize" and trainer is not None and hasattr(trainer, "trajectory"):
            return [(item.source_index, item.camera.center, item.is_virtual) for item in trainer.trajectory]
        if not self.scene.cameras:
            return []
        if self.order_preview is None:
            from training.scene.scene import camera_normalization
            from training.stylize.view_order import view_order
            from training.stylize.virtual_views import trajectory

            cfg = self.training.stylize
            cams = self.scene.cameras
            # the extent the stylizer passes (the scene's), so the preview is the order the run will follow
            order = view_order(cams, cfg.view_order, seed=cfg.seed, extent=camera_normalization(cams)[1])
            self.order_preview = [(item.source_index, item.camera.center, item.is_virtual)
                                  for item in trajectory(cams, order, cfg.virtual_views)]
        return self.order_preview

    def current_view_index(self) -> int | None:
        """Trajectory position of the view the stylizer optimises now (None when no stylizer runs)."""
        trainer = self.session.trainer
        if self._stage == "stylize" and trainer is not None and hasattr(trainer, "trajectory_position"):
            return trainer.trajectory_position
        return None
