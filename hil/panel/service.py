"""The rig service: the one process that owns the plant (the FMU, or the rig's serial link)
and records its runs; the panel's web server only talks to it (Klipper's split: klippy owns
the MCU, Moonraker serves the web).

It reads one JSON action a line on stdin and writes JSON events a line on stdout: the reply
to each action at once (accepted or refused), ``samples`` batches every
:data:`BATCH_PERIOD` s during a motion, ``status`` every :data:`STATUS_PERIOD` s and
``done`` when an action ends. Each run is recorded by :class:`hil.host.recording.RunRecorder`
as its samples come, in this process, so the web server crashing loses nothing: this
process then sees stdin close, stops the rig (no operator can press STOP any more),
records every sample up to the standstill, closes the run and exits. A dead service leaves
the rig to the MCU's heartbeat watchdog (docs/rig-protocol-behaviour.md section 7).

Every motion goes through the existing back-ends and link (hil.host.backends,
hil.host.homing), so the
host's limits and the MCU's are those of ``hil run``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.host.backends import (
    MAX_SPEED,
    FmuPlant,
    Plant,
    RigPlant,
    RigSetup,
    RunStoppedError,
    fault_names,
    link_report,
    simulated_speed_limit,
)
from hil.host.experiment import CycleCounter, planned_trajectory, profile_cycles
from hil.host.experiment import reciprocating_trajectory as reciprocating
from hil.host.recording import RecordingError, RunMeta, RunRecorder, default_run_dir, record_run
from hil.host.samples import Sample, Trajectory, TrajectoryError
from hil.link import protocol as p
from toggle.params import load_preset

#: Seconds between two batches of samples (the page draws each batch once).
BATCH_PERIOD = 0.04
#: Seconds between two status events.
STATUS_PERIOD = 0.1
#: The MCU's heartbeat timeout the idle session asks for, ms (the protocol's longest).
IDLE_HEARTBEAT_MS = 1000
#: Actions that move the rig (one at a time, refused while another runs).
MOTIONS = ("home", "jog", "run", "check", "tare", "span", "store", "clear")


class OperatorStopError(RunStoppedError):
    """The panel's STOP (or the web server gone) ended the motion."""


class Outbox:
    """JSON lines to stdout, whole lines from any thread."""

    def __init__(self, stream: Any = None) -> None:
        self._stream = stream or sys.stdout
        self._lock = threading.Lock()

    def __call__(self, kind: str, **fields: Any) -> None:
        line = json.dumps({"type": kind, **fields}, allow_nan=False, default=str)
        with self._lock:
            try:
                self._stream.write(line + "\n")
                self._stream.flush()
            except (OSError, ValueError):
                pass  # the web server is gone: the run goes on into its record


class RigService:
    """Owns the plant, runs one motion at a time, streams what it measures."""

    def __init__(self, backend: str, port: str | None, runs: Path, emit: Outbox,
                 preset: str = "chang2021", force_limit: float = 400.0,
                 timing: dict[str, float | None] | None = None) -> None:
        self.backend, self.port, self.runs, self.emit = backend, port, runs, emit
        # the link's timing as hil run's --ack-ms, --watchdog-ms, --heartbeat-ms (None:
        # measured when the session opens), s and ms as RigPlant takes them
        self.timing = {"ack_timeout": None, "telemetry_timeout": None, "heartbeat_ms": None,
                       **(timing or {})}
        self.setup = RigSetup(preset=preset, force_limit=force_limit)
        self.stop_requested = threading.Event()
        self.closing = threading.Event()
        self.busy: str | None = None
        self.link = None  # the idle session with the rig (rig back-end only)
        self.plant: Plant | None = None  # the plant of the run in progress
        self.message = ""
        self.last: Sample | None = None
        self.cycles, self.cycles_total, self.run_dir = 0, 0, None
        self._pending: list[tuple[float, Sample, float]] = []
        self._pending_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._plans: dict[str, Trajectory] = {}
        self._connect_lock = threading.Lock()

    # --- the rig's session -----------------------------------------------------------------

    def connect(self) -> None:
        """Open the session (rig back-end), or a new one when the last one failed; a failure
        is reported in the status. From the action thread and the publisher: locked."""
        with self._connect_lock:
            self._connect()

    def _connect(self) -> None:
        if self.link is not None and self.link.failure is not None:
            self.message = f"the session ended ({self.link.failure}): reconnecting"
            self.disconnect()  # a watchdog or a lost link ends a session: open a new one
        if self.backend != "rig" or self.link is not None:
            return
        from hil.link.errors import RigError
        from hil.link.serial_link import SerialLink

        # realtime: the reader thread (and its heartbeats) at SCHED_FIFO when the OS permits,
        # as RigPlant's. One session for the panel's life (runs included, RigPlant's
        # session=): it asks the MCU for the protocol's longest heartbeat timeout unless one
        # is given, as a loaded host idling for hours must not latch HEARTBEAT_LOST. At its
        # end it clears the faults latched during it, as hil run's session does (never an
        # ESTOP, never a fault found latched at open).
        t = self.timing
        link = SerialLink(self.port, realtime=True, ack_timeout=t["ack_timeout"],
                          telemetry_timeout=t["telemetry_timeout"],
                          heartbeat_timeout_ms=IDLE_HEARTBEAT_MS if t["heartbeat_ms"] is None
                          else round(t["heartbeat_ms"]))
        try:
            link.open()
            if link.status.state == p.State.IDLE:
                link.configure(link.config_for())
        except (RigError, OSError) as exc:
            link.close()
            self.message = f"rig at {self.port}: {exc}"
            return
        self.link = link

    def disconnect(self) -> None:
        if self.link is not None:
            self.link.close()  # STOP, standstill, BYE; never raises
            self.link = None

    @property
    def active_link(self) -> Any:
        """The session that moves the rig now: the run's, else the idle one."""
        plant_link = getattr(self.plant, "link", None)
        return plant_link if plant_link is not None else self.link

    # --- actions ---------------------------------------------------------------------------

    def handle(self, msg: dict[str, Any]) -> None:
        """One action from the web server (already validated there): reply at once."""
        ident, action, args = msg.get("id"), msg.get("action"), msg.get("args") or {}
        if action == "stop":
            self.stop(msg.get("t_click"))
            self.emit("reply", id=ident, ok=True)
        elif action == "estop":
            self.estop()
            self.emit("reply", id=ident, ok=True)
        elif action in MOTIONS:
            if self.busy is not None:
                self.emit("reply", id=ident, ok=False, error=f"busy: {self.busy} in progress; "
                                                             "STOP it or wait")
                return
            self.busy = action
            self.stop_requested.clear()
            self._thread = threading.Thread(target=self._do, args=(action, args), daemon=True)
            self._thread.start()
            self.emit("reply", id=ident, ok=True)
        else:
            self.emit("reply", id=ident, ok=False, error=f"unknown action {action!r}")

    def stop(self, t_click: float | None = None) -> None:
        """Controlled stop of whatever moves: the run loop ends at its next sample; on the
        rig the stop sequence goes out now, from this thread."""
        self.stop_requested.set()
        link = self.active_link
        if link is not None and self.busy is not None:
            threading.Thread(target=link.stop_quietly, daemon=True).start()

    def estop(self) -> None:
        self.stop_requested.set()
        link = self.active_link
        if link is not None:
            threading.Thread(target=link.estop, daemon=True).start()

    def _check(self) -> None:
        if self.stop_requested.is_set():
            raise OperatorStopError("STOP from the panel" if not self.closing.is_set()
                               else "the panel's web server went away: stopped")

    def _do(self, action: str, args: dict[str, Any]) -> None:
        ok, text, result = True, "", None
        try:
            if action == "run":
                text = self._run(args)
                ok = not text.startswith("stopped")
            else:
                result = self._rig_action(action, args)
                text = f"{action} done"
        except Exception as exc:  # every failure is the operator's message, none kills us
            ok, text = False, f"{action}: {exc}"
        finally:
            self.busy, self.plant = None, None
        self.message = text
        self.emit("done", action=action, ok=ok, message=text, result=result)

    def _rig_action(self, action: str, args: dict[str, Any]) -> Any:
        if self.backend != "rig":
            raise RunStoppedError("the simulated rig has no home switch, faults to clear, "
                                  "jog or bring-up: start the panel with --real --port")
        self.connect()
        if self.link is None:
            raise RunStoppedError(self.message)
        link = self.link
        if action == "clear":
            link.clear_fault()
            return None
        if action == "home":
            from hil.host.homing import home

            return {"distance_m": home(link)}
        from hil.host import bringup  # the bring-up functions (issue 44)

        call: dict[str, Callable[..., Any]] = {
            "jog": lambda: bringup.jog(link, **args), "tare": lambda: bringup.tare(link, **args),
            "span": lambda: bringup.span(link, **args),
            "store": lambda: bringup.store_calibration(link, **args),
            "check": lambda: bringup.sensor_check(link)}
        try:
            return call[action]().to_dict()
        except bringup.BringupError as exc:
            raise RunStoppedError(str(exc)) from None

    # --- runs ------------------------------------------------------------------------------

    def trajectory(self, args: dict[str, Any]) -> tuple[Trajectory, str, float | None]:
        """The job's trajectory, its description and its constant speed (m/s, else None)."""
        s, cycles = self.setup, int(args["cycles"])
        if args["job"] == "speed":
            speed = float(args["speed"])
            return (reciprocating(load_preset(s.preset), speed, cycles, s.period),
                    f"reciprocating at {speed * 1e3:g} mm/s", speed)
        if args["job"] == "plan":
            forward = Trajectory.from_csv(Path(args["plan"]), period=s.period)
            return profile_cycles(forward, cycles), f"plan {args.get('name', 'uploaded')}", None
        if s.preset not in self._plans:  # the default job: hil run's planned stroke
            self.message = f"planning the default job for {s.preset}"
            self._plans[s.preset] = planned_trajectory(
                s.preset, s.period, mu=s.mu, x_contact=s.planned_mold, errors=s.errors,
                masses=s.dynamics)
        return (profile_cycles(self._plans[s.preset], cycles),
                "planned (minimum peak input force)", None)

    def _run(self, args: dict[str, Any]) -> str:
        trajectory, source, speed = self.trajectory(args)
        setup = self.setup
        if args["job"] == "default":
            from dataclasses import replace

            setup = replace(setup, x_contact=setup.planned_mold)
        if self.backend == "rig":  # the panel's session: no second handshake
            self.connect()
            if self.link is None:
                raise RunStoppedError(self.message)
            plant: Plant = RigPlant(self.port, notify=self._notify, session=self.link,
                                    **self.timing)
        else:
            plant = FmuPlant(notify=self._notify)
        try:
            return self._record(plant, setup, trajectory, source, speed, int(args["cycles"]))
        finally:
            plant.deactivate()

    def _record(self, plant: Plant, setup: RigSetup, trajectory: Trajectory, source: str,
                speed: float | None, cycles: int) -> str:
        plant.configure(setup)
        plant.check(trajectory)
        meta = RunMeta.for_experiment(load_preset(setup.preset), backend=plant.name,
                                      cycles=cycles, delta_r8=setup.delta_r8,
                                      period=setup.period, speed=speed, profile=source,
                                      settings={"panel": True, "force_limit": setup.force_limit})
        counter = CycleCounter(*setup.stroke)
        self.cycles, self.cycles_total = 0, cycles
        plant.activate()
        self.plant = plant
        self._check()  # a STOP during the activation (homing, handshake)
        rec = RunRecorder(meta, default_run_dir(f"panel-{plant.name}", self.runs))
        self.run_dir = str(rec.dir)
        # the page's message says what now moves (it said "homing" for the whole run)
        self._notify(f"running: {source}, {cycles} cycle{'s' if cycles != 1 else ''}, "
                     f"recorded in {rec.dir}")
        period, previous = setup.period, [None]

        def on_sample(sample: Sample) -> None:
            if counter.update(sample.x_cmd):
                self.cycles += 1
            last = previous[0]
            v = 0.0 if last is None else (sample.x_cmd - last.x_cmd) / period
            previous[0] = self.last = sample
            with self._pending_lock:
                self._pending.append((time.time(), sample, v))

        with rec:
            reason = record_run(plant, trajectory, rec, self._check, on_sample)
        self._flush_samples()
        return (f"stopped: {reason}; {rec.count} samples in {rec.dir}" if reason
                else f"run complete: {rec.count} samples in {rec.dir}")

    def _notify(self, text: str) -> None:
        self.message = text
        self.emit("notice", message=text)

    # --- streaming -------------------------------------------------------------------------

    def _flush_samples(self) -> None:
        with self._pending_lock:
            batch, self._pending = self._pending, []
        if not batch:
            return
        period = self.setup.period
        self.emit("samples", rx=[round(r, 4) for r, _, _ in batch],
                  mcu_t=[round(s.index * period, 4) for _, s, _ in batch],
                  t=[round(s.t, 4) for _, s, _ in batch],
                  x=[s.x_cmd for _, s, _ in batch], platen=[s.platen for _, s, _ in batch],
                  force=[round(s.force, 4) for _, s, _ in batch],
                  v=[round(v, 6) for _, _, v in batch])

    def status(self) -> dict[str, Any]:
        """What the page shows beside the charts: state, faults, homing, limits, link."""
        s = self.setup
        lo, hi = s.travel_limits
        limits: dict[str, Any] = {"force_limit_n": s.force_limit, "travel_m": [lo, hi],
                                  "speed_max_m_s": None}
        out: dict[str, Any] = {"backend": self.backend, "busy": self.busy,
                               "message": self.message, "cycles": self.cycles,
                               "cycles_total": self.cycles_total, "run_dir": self.run_dir,
                               "limits": limits}
        link = self.active_link
        if self.backend == "fmu":
            limits["speed_max_m_s"] = simulated_speed_limit(s.preset)
            last = self.last
            out.update(connected=True, state="RUNNING" if self.busy else "IDLE", faults=[],
                       homed=None, link={},
                       position=None if last is None else {
                           "x": last.x_cmd, "platen": last.platen, "force": last.force})
            return out
        limits["speed_max_m_s"] = MAX_SPEED
        tel = None if link is None else link.status
        if tel is None:
            out.update(connected=False, state="DISCONNECTED", faults=[], homed=None, link={})
            return out
        sc, cfg = link.scaling, link.config
        limits["mcu"] = {"force_limit_n": cfg.force_limit_n, "steps": [cfg.steps_min,
                                                                        cfg.steps_max],
                         "heartbeat_timeout_ms": cfg.heartbeat_timeout_ms}
        faults = fault_names(tel.faults)
        out.update(connected=True, state=p.State(tel.state).name,
                   faults=[] if faults == "none" else faults.split(" | "),
                   homed=bool(tel.flags & p.TelemetryFlag.REFERENCED),
                   home_switch=bool(tel.flags & p.TelemetryFlag.HOME_SWITCH),
                   position={"x": sc.x(tel.steps, s.stroke[0]), "platen": sc.platen(tel.enc),
                             "force": sc.force(tel.load_raw)},
                   link=link_report(link))
        return out

    def publish(self) -> None:
        """Samples every BATCH_PERIOD, status every STATUS_PERIOD, until closed."""
        next_status = 0.0
        while not self.closing.is_set():
            self._flush_samples()
            if self.busy is None and self.link is not None:
                self.link.drain()  # idle telemetry: its status is kept, its queue emptied
                if self.link.failure is not None:
                    self.connect()  # a session the watchdog ended: the status of a new one
            now = time.monotonic()
            if now >= next_status:
                next_status = now + STATUS_PERIOD
                try:
                    self.emit("status", **self.status())
                except Exception as exc:  # a link closing under us: the next one is whole
                    self.emit("notice", message=f"status: {exc}")
            time.sleep(BATCH_PERIOD)

    def shut_down(self) -> None:
        """The web server is gone (stdin closed): stop, let the run record its standstill,
        close the session."""
        self.closing.set()
        self.stop()
        if self._thread is not None:
            self._thread.join(timeout=30.0)
        self.disconnect()


def main(argv: list[str] | None = None) -> int:
    a = argparse.ArgumentParser(prog="python -m hil.panel.service")
    a.add_argument("--backend", choices=("fmu", "rig"), default="fmu")
    a.add_argument("--port", default=None)
    a.add_argument("--runs", type=Path, default=Path("runs"))
    a.add_argument("--preset", default="chang2021")
    a.add_argument("--force-limit", type=float, default=400.0)
    for name in ("ack-ms", "watchdog-ms", "heartbeat-ms"):
        a.add_argument(f"--{name}", type=float, default=None)
    args = a.parse_args(argv)
    ms = {"ack_timeout": args.ack_ms, "telemetry_timeout": args.watchdog_ms}
    timing = {**{k: None if v is None else v * 1e-3 for k, v in ms.items()},
              "heartbeat_ms": args.heartbeat_ms}
    emit = Outbox()
    service = RigService(args.backend, args.port, args.runs, emit, args.preset,
                         args.force_limit, timing)
    service.connect()
    threading.Thread(target=service.publish, daemon=True).start()
    emit("ready", backend=args.backend)
    for line in sys.stdin:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            emit("notice", message="service: a line that is not JSON was ignored")
            continue
        if isinstance(msg, dict):
            service.handle(msg)
    service.shut_down()
    return 0


if __name__ == "__main__":  # pragma: no cover
    try:
        sys.exit(main())
    except (RecordingError, TrajectoryError, KeyboardInterrupt):
        sys.exit(1)
