"""The live session: a trainer running in a torch thread beside the UI, talking to it only in messages. It is the
one door into a trainer: nothing else in the app holds one.

The UI (or a test) sends commands (pause, resume, single step, stop, pause at N; live settings, ``update_config``;
and the typed commands of ``submit``: ``Keep`` (a deletion or crop), ``SetRegion`` (the Gaussians a stylization
changes), ``UseModel`` (a whole read of the model, an export)) and reads, without ever blocking on a step: the
events the trainer emits and the session's own typed messages (``poll()``: ``StageBegan``, ``StateChanged``,
``Saved``, ``Failed``, ``Said``), the latest model (``snapshot()``, the trainer's consistent copy), the trainer's
own status (``trainer_status()``: the frozen ``TrainerStatus`` it publishes after each step: capacity map,
utilisation, trajectory position, pass, losses, gradient balance), and a status line's figures (``status()``). The
trainer never waits on a frame: commands are read between steps.

A run is a list of stages (``Stage``): reconstruct, then stylize, or either alone; from photos, structure from
motion first (its "trainer" runs the whole SfM in one step, and Stop reaches it inside that step: ``interrupt``).
Each stage builds its trainer inside the thread (loading a scene or VGG takes seconds, and the window must stay live
meanwhile), steps it to the end, and saves its outputs. Stop, window close and Ctrl-C save too: a reconstruction
writes its checkpoint and PLY, a stylization its current model (also when the stop comes during its final colour
transfer: a save cancelled part way saves again, quickly, what there is, and the stage's further outputs and the
next stage are skipped); an exception in the trainer becomes one line in the UI and the session goes on. Settings
given while a stage's trainer is being built are kept for that trainer (``update_config``), never handed to the last
stage's.

The session never sleeps the trainer: sharing the CPU with the view is the view's business (it limits how much of
the time it spends drawing while a trainer runs; see view3d.py).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from training.core import stop
from training.core.messages import Cancelled, ModelSnapshot, Stepped, TrainerEvent
from training.core.status import SfmStatus, StylizeStatus, TrainerStatus
from training.core.trainer import Command, Trainer, UseModel

STATES = ("idle", "loading", "running", "paused", "finishing", "finished", "stopped", "error")


# ---------------------------------------------------------------------------------- the session's own news (poll)
@dataclass(frozen=True)
class StageBegan:
    """A stage began (its trainer is being built)."""

    stage: str


@dataclass(frozen=True)
class StateChanged:
    """The run's state is now ``state`` (one of STATES)."""

    state: str
    stage: str


@dataclass(frozen=True)
class Saved:
    """A stage wrote its model to ``path``."""

    path: str
    stage: str


@dataclass(frozen=True)
class Failed:
    """Something went wrong: one line for the window; the session goes on."""

    text: str
    stage: str


@dataclass(frozen=True)
class Said:
    """A line for the user that is no error (what the console prints)."""

    text: str
    stage: str


SessionMessage = StageBegan | StateChanged | Saved | Failed | Said


# ---------------------------------------------------------------------------------- the session's own commands
@dataclass(frozen=True)
class _Pause:
    pass


@dataclass(frozen=True)
class _Resume:
    pass


@dataclass(frozen=True)
class _SingleStep:
    """One step, then paused."""


@dataclass(frozen=True)
class _PauseAt:
    step: int | None


@dataclass(frozen=True)
class _Wake:
    """Nothing to do: a paused thread waiting for a command looks at the stop again."""


@dataclass(frozen=True)
class _Call:
    """A trainer's command (training/core/trainer.py) for the trainer of ``stage``, its result into ``future``."""

    command: Command
    future: Future
    trainer: Trainer
    stage: str


SessionCommand = _Pause | _Resume | _SingleStep | _PauseAt | _Wake | _Call


@dataclass
class Stage:
    """One stage of a run. ``build(previous)`` makes the trainer (on the training thread; ``previous`` is the last
    stage's ``save`` result, or None); ``save(trainer, finished, cancel)`` writes the outputs and returns what the
    next stage builds from; it runs when the schedule ends (finished=True) and on stop or error (finished=False,
    where it must be quick: keep the model, skip the long final passes). ``outputs(trainer, saved, say)``, when
    given, runs after a finished stage has saved (still on the training thread, the state "finishing"): the rest of
    what the stage writes (reports, renders); ``say(line)`` puts a line in the window at once (a ``Said`` message).
    ``stopped(trainer)``, when given, is the one line that says what a stop before the stage finished left (SfM:
    nothing); it goes to the window and to ``LiveSession.notes``, which the console prints once the window is
    closed. ``began(trainer)``, when given, is the line said once the trainer is built (what the stage will do)."""

    name: str
    build: Callable[[Any], Any]
    save: Callable[[Any, bool, Callable[[], bool]], Any]
    outputs: Callable[[Any, Any, Callable[[str], None]], None] | None = None
    stopped: Callable[[Any], str] | None = None
    began: Callable[[Any], str] | None = None


@dataclass
class SessionStatus:
    stage: str = ""
    state: str = "idle"
    step: int = 0
    total: int = 0
    steps_per_second: float = 0.0
    seconds_left: float | None = None
    error: str = ""
    last_metrics: dict[str, float] = field(default_factory=dict)
    detail: str = ""  # what the stage does now, in words, when its steps are not iterations (SfM: its phase)


class LiveSession:
    """Runs stages on a training thread. Every public method may be called from the UI thread and returns at once
    (``close`` waits for the thread to save and end, at most ``timeout`` seconds)."""

    def __init__(self, history: int = 5000):
        self._commands: queue.Queue = queue.Queue()
        self._out: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._trainer = None
        self._original: tuple = (None, None)  # (a stylizer's original_sh, its numpy copy): original_colours()
        self._status = SessionStatus()
        self._stop = threading.Event()
        self._paused = False
        self._pause_at: int | None = None
        self._step_times: deque[float] = deque(maxlen=20)
        # while a stage builds its trainer, ``_trainer`` is still the last stage's (or the last run's): settings
        # given meanwhile wait here for the trainer being built (they are the new run's, not the old trainer's)
        self._building = False
        self._pending_config: dict[str, Any] = {}
        self._taking_calls = False  # under _lock: submit() queues only while the thread will still answer
        self.saved: list[Path] = []
        self.notes: list[str] = []  # the lines of stopped stages (Stage.stopped), for the console after the window
        self.history: deque[dict[str, float]] = deque(maxlen=history)  # step metrics, for the curves

    # ------------------------------------------------------------------ commands (UI thread)
    def start(self, stages: list[Stage], paused: bool = False) -> None:
        if self.running:
            raise RuntimeError("a run is already going: stop it first")
        self._stop.clear()
        self._paused = paused
        self._pause_at = None
        self._commands = queue.Queue()
        self.history.clear()
        self._thread = threading.Thread(target=self._run, args=(list(stages),), name="splatstyler-trainer",
                                        daemon=True)
        with self._lock:
            self._building, self._pending_config = True, {}
            self._status.stage = stages[0].name if stages else ""
            self._taking_calls = True
        self._set(state="loading", error="", step=0, total=0, last_metrics={}, steps_per_second=0.0,
                  seconds_left=None, detail="")
        self._thread.start()

    def pause(self) -> None:
        self._commands.put(_Pause())

    def resume(self) -> None:
        self._commands.put(_Resume())

    def single_step(self) -> None:
        """One step, then paused."""
        self._commands.put(_SingleStep())

    def pause_at(self, step: int | None) -> None:
        self._commands.put(_PauseAt(step))

    def stop(self) -> None:
        """Stop the run: between two steps, or inside a long call of the training thread (a whole SfM, a load, the
        outputs), which checks the stop between its units of work (training/core/stop.py)."""
        self._stop.set()
        self._commands.put(_Wake())

    def release(self) -> None:
        """Forget a run that has ended: its trainer stops being the model the viewer shows and edits (opening
        another model does this). The run's files and its curves stay."""
        if self.running:
            raise RuntimeError("a run is going: stop it first")
        self._trainer, self._original = None, (None, None)
        with self._lock:
            self._status = SessionStatus()

    def submit(self, command: Command) -> Future:
        """Hand ``command`` to the trainer: it is carried out on the training thread between two steps (never during
        one), and the Future holds its result or its refusal (a ValueError in one line). Every change to a running
        trainer's Gaussians (deletions, crops, the stylization's region) and every read that must be whole (an
        export) goes through here, in the order submitted.

        The command belongs to the trainer running now (whose model the user acted on): it is carried out on that
        trainer, at the latest when its stage ends and before the stage saves; once the next stage has begun it is
        refused (the Future's exception says so), never carried out on the next stage's trainer. A ``UseModel``
        given when the run has ended (its trainer still held) is answered at once: no step can run meanwhile."""
        trainer = self._trainer
        future: Future = Future()
        if isinstance(command, UseModel) and trainer is not None and not self.running:
            future.set_running_or_notify_cancel()
            self._carry_out(command, trainer, future)
            return future
        with self._lock:  # not between the thread's last look at the queue and its end: nobody would answer
            if not self.running or trainer is None or not self._taking_calls:
                raise ValueError("no trainer is running")
            self._commands.put(_Call(command, future, trainer, self._status.stage))
        return future

    def update_config(self, **changes: Any) -> str | None:
        """Hand live settings to the running trainer through its ``update_config`` (the one way settings reach a
        trainer: it checks them and its next step takes them). None when handed over, else the refusal in one line:
        a setting the trainer does not have, one fixed when it started (``FIXED_AT_START``), a value it refuses.

        While a stage is loading (its trainer not built yet) the settings are kept for that trainer: it starts with
        them (they are checked then, and a refusal is a ``Failed`` message)."""
        if not self.running:
            return "no trainer is running"
        with self._lock:
            if self._building:
                self._pending_config.update(changes)
                return None
            trainer = self._trainer
        if trainer is None:
            return "no trainer is running"
        return _config_refusal(trainer, changes)

    def close(self, timeout: float = 600.0) -> None:
        """Stop, let the stage save, wait for the thread."""
        self.stop()
        if self._thread is not None:
            self._thread.join(timeout)

    # ------------------------------------------------------------------ reads (UI thread)
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def has_trainer(self) -> bool:
        """A trainer is held (running, or ended and not released): the view shows its model, not the document's."""
        return self._trainer is not None

    def trainer_status(self, kind: type[TrainerStatus] = TrainerStatus) -> TrainerStatus | None:
        """The status the trainer published last (its own stage's: while the next stage loads, the last stage's
        trainer is still the one held); None when none is held, or when the one held is not of type ``kind``
        (``StylizeStatus``: a stylization's)."""
        trainer = self._trainer
        status = None if trainer is None else trainer.status()
        return status if isinstance(status, kind) else None

    def snapshot(self) -> ModelSnapshot | None:
        trainer = self._trainer
        return None if trainer is None else trainer.snapshot()

    def original_colours(self) -> np.ndarray | None:
        """A stylization's input colours (N, K, 3) over its current rows, read-only (what style strength blends
        back); None when the trainer held is no stylization. The same array until its rows change."""
        status = self.trainer_status(StylizeStatus)
        sh = None if status is None else status.original_sh
        if sh is None:
            return None
        if self._original[0] is not sh:
            array = sh.detach().cpu().numpy()
            array.setflags(write=False)
            self._original = (sh, array)
        return self._original[1]

    def cameras(self) -> list | None:
        """The cameras the running stage has placed so far (SfM's registered photos, pinhole Camera), or None for
        a stage that places none."""
        status = self.trainer_status(SfmStatus)
        return None if status is None else list(status.cameras)

    def poll(self) -> list[TrainerEvent | SessionMessage]:
        """Everything that happened since the last poll, oldest first; never blocks."""
        out = []
        while True:
            try:
                out.append(self._out.get_nowait())
            except queue.Empty:
                return out

    def status(self) -> SessionStatus:
        with self._lock:
            s = self._status
            return SessionStatus(s.stage, s.state, s.step, s.total, s.steps_per_second, s.seconds_left, s.error,
                                 dict(s.last_metrics), s.detail)

    # ------------------------------------------------------------------ the training thread
    def _set(self, **fields_: Any) -> None:
        with self._lock:
            for k, v in fields_.items():
                setattr(self._status, k, v)
            if "state" in fields_:
                self._out.put(StateChanged(fields_["state"], self._status.stage))

    def _on_event(self, event: TrainerEvent) -> None:
        self._out.put(event)
        if isinstance(event, Stepped):
            self.history.append({"step": float(event.step), **event.metrics})
            with self._lock:
                self._status.step = event.step
                self._status.total = int(event.metrics.get("total_iters", self._status.total))
                self._status.last_metrics = event.metrics
                self._status.detail = event.message
                if "seconds_left" in event.metrics:  # a stage that estimates its own time (SfM, by phase)
                    left = event.metrics["seconds_left"]
                    self._status.seconds_left = left if left >= 0 else None

    def _handle(self, command: SessionCommand) -> bool:
        """Apply one command; True when it asks for exactly one step."""
        if isinstance(command, _Pause):
            self._paused = True
            self._set(state="paused")
        elif isinstance(command, _Resume):
            self._paused = False
            self._set(state="running")
        elif isinstance(command, _PauseAt):
            self._pause_at = command.step
        elif isinstance(command, _SingleStep):
            self._paused = True
            return True
        elif isinstance(command, _Call):
            if not command.future.set_running_or_notify_cancel():
                pass
            elif command.trainer is not self._trainer:
                command.future.set_exception(RuntimeError(f"the {command.stage} stage ended before this reached its "
                                                          "model: do it again on the model shown now"))
            else:
                self._carry_out(command.command, command.trainer, command.future)
        return False

    def _carry_out(self, command: Command, trainer: Trainer, future: Future) -> None:
        """``command`` on ``trainer`` (on the training thread, between steps, or on an ended trainer); its result or
        its refusal goes to ``future``."""
        try:
            future.set_result(trainer.apply(command))
        except Exception as exc:  # noqa: BLE001  (the caller reads it from the future)
            future.set_exception(exc)

    def _calls_before_save(self) -> None:
        """The calls queued for the trainer whose stage ends run now, before it saves (a deletion clicked during
        its last step is in the saved model); the other commands stay queued, in order."""
        kept = []
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                break
            if isinstance(command, _Call):
                self._handle(command)
            else:
                kept.append(command)
        for command in kept:
            self._commands.put(command)

    def _next_commands(self) -> bool:
        """Drain the commands; while paused wait for one (no CPU spent). True when one step is asked for."""
        one_step = False
        while True:
            try:
                command = self._commands.get(block=self._paused and not one_step and not self._stop.is_set())
            except queue.Empty:
                return one_step
            one_step = self._handle(command) or one_step
            if self._stop.is_set():
                return False

    def _run(self, stages: list[Stage]) -> None:
        try:
            # Stop reaches the long calls of this thread too (loading, scoring, writing the outputs): they check
            # between their units of work (training/core/stop.py), so a close waits on no whole pass
            with stop.watching(self._stop.is_set):
                self._run_stages(stages)
        finally:
            with self._lock:
                self._building = False
            self._trainer_gone()

    def _trainer_gone(self) -> None:
        """The run is over: calls still queued will never run; their futures say so (nobody waits forever)."""
        with self._lock:
            self._taking_calls = False
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return
            if isinstance(command, _Call):
                command.future.set_exception(RuntimeError("the run ended before this change reached the trainer"))

    def _run_stages(self, stages: list[Stage]) -> None:
        previous = None
        for stage in stages:
            if self._stop.is_set():
                break
            with self._lock:
                self._status.stage = stage.name
                self._building = True
                # the last stage's figures are not this one's (a panel reading them would take a reconstruction's
                # for the stylization's)
                self._status.last_metrics, self._status.step, self._status.total = {}, 0, 0
                self._status.detail, self._status.seconds_left, self._status.steps_per_second = "", None, 0.0
            self._out.put(StageBegan(stage.name))
            self._step_times.clear()  # the last stage's step times are not this one's (an SfM "step" is minutes)
            # each stage's curves start afresh: a stylization's steps count from 0 again, and its "loss" joined to
            # the reconstruction's drew a line back across the plot
            self.history.clear()
            self._set(state="loading")
            trainer = None
            try:
                trainer = stage.build(previous)
                trainer.add_listener(self._on_event)
                with self._lock:
                    self._trainer, self._building = trainer, False
                    pending, self._pending_config = self._pending_config, {}
                self._take_pending(stage, trainer, pending)
                if stage.began is not None:
                    self._out.put(Said(stage.began(trainer), stage.name))
                self._set(state="paused" if self._paused else "running", total=trainer.total_iters,
                          step=trainer.status().step)
                self._train(trainer)
                finished = trainer.done
                self._calls_before_save()
                self._set(state="finishing")
                try:
                    # a stopped stage's save is not stopped; a finished one's final passes are (Cancelled below)
                    with stop.saving() if not finished else contextlib.nullcontext():
                        previous = stage.save(trainer, finished, self._stop.is_set)
                except Cancelled:  # stopped during the stage's long final passes: what there is, saved quickly
                    with stop.saving():
                        finished, previous = False, stage.save(trainer, False, lambda: True)
                if previous is not None:
                    self._out.put(Saved(str(previous), stage.name))
                    self.saved.append(Path(str(previous)))
                if not finished and stage.stopped is not None:
                    line = stage.stopped(trainer)
                    self.notes.append(line)
                    self._out.put(Said(line, stage.name))
                if not finished or self._stop.is_set():  # a stop during the save: no outputs, no next stage
                    self._set(state="stopped")
                    return
                if stage.outputs is not None and not self._stage_outputs(stage, trainer, previous):
                    self._set(state="stopped")
                    return
            except KeyboardInterrupt:  # the stop, seen inside a long call: what there is, saved quickly
                self._save_stopped(stage, trainer)
                return
            except Exception as exc:  # one line in the UI; the window and the session go on
                line = _one_line(exc)
                self._set(state="error", error=line)
                self._out.put(Failed(line, stage.name))
                if trainer is not None:
                    try:
                        with stop.saving():
                            saved = stage.save(trainer, False, lambda: True)
                        if saved is not None:
                            self._out.put(Saved(str(saved), stage.name))
                            self.saved.append(Path(str(saved)))
                    except Exception as exc2:  # noqa: BLE001  (the first error is the one to show)
                        self._out.put(Failed(f"could not save: {_one_line(exc2)}", stage.name))
                return
            finally:
                with self._lock:
                    self._building = False
        self._set(state="finished" if not self._stop.is_set() else "stopped")

    def _save_stopped(self, stage: Stage, trainer) -> None:
        """A stop that came inside the stage's build, its step or its final passes: the model as it is (none before
        the trainer was built), the stage's stop line, the state "stopped"."""
        if trainer is not None:
            try:
                with stop.saving():
                    saved = stage.save(trainer, False, lambda: True)
                if saved is not None:
                    self._out.put(Saved(str(saved), stage.name))
                    self.saved.append(Path(str(saved)))
            except Exception as exc:  # noqa: BLE001  (said; the stop goes on)
                self._out.put(Failed(f"could not save: {_one_line(exc)}", stage.name))
        if stage.stopped is not None:
            line = stage.stopped(trainer)
            self.notes.append(line)
            self._out.put(Said(line, stage.name))
        self._set(state="stopped")

    def _take_pending(self, stage: Stage, trainer, pending: dict[str, Any]) -> None:
        """Settings given while the trainer was being built: its first step takes them."""
        for name, value in pending.items():  # each on its own: one the trainer cannot take does not stop the rest
            refusal = _config_refusal(trainer, {name: value})
            if refusal:
                self._out.put(Failed(refusal, stage.name))

    def _stage_outputs(self, stage: Stage, trainer, saved) -> bool:
        """A finished stage's further outputs; their failure is one line, and the model saved and the next stage
        stand. False when a stop came while they were written (the run ends)."""
        def say(line: str) -> None:
            self._out.put(Said(line, stage.name))

        try:
            stage.outputs(trainer, saved, say)
        except KeyboardInterrupt:  # stopped while writing them: the model stands, and the run ends here
            say(f"{stage.name}: stopped while writing the report and renders; the model is saved in {saved}")
            return False
        except Exception as exc:  # noqa: BLE001  (the model is saved; the run goes on)
            self._out.put(Failed(f"{stage.name} outputs: {_one_line(exc)}", stage.name))
        return True

    def _train(self, trainer) -> None:
        while not trainer.done and not self._stop.is_set():
            one_step = self._next_commands()
            if self._stop.is_set():
                return
            if self._paused and not one_step:
                continue
            t0 = time.perf_counter()
            trainer.step()
            dt = time.perf_counter() - t0
            self._step_times.append(dt)
            mean = sum(self._step_times) / len(self._step_times)
            step = self._status.step
            if self._pause_at is not None and step >= self._pause_at:
                self._pause_at = None
                self._paused = True
            with self._lock:
                self._status.steps_per_second = 1.0 / mean if mean > 0 else 0.0
                left = max(0, trainer.total_iters - step)
                self._status.seconds_left = left * mean
            if one_step or (self._paused and self._status.state != "paused"):
                self._set(state="paused")


def _config_refusal(trainer: Trainer, changes: dict[str, Any]) -> str | None:
    """``trainer.update_config(**changes)``; its refusal as one line, None when taken."""
    try:
        trainer.update_config(**changes)
    except ValueError as exc:
        return str(exc)
    return None


def _one_line(exc: BaseException) -> str:
    from training.core.errors import InputError

    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return text if isinstance(exc, InputError) else f"{type(exc).__name__}: {text}"
