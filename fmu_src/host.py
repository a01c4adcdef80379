"""Host-side helpers for running this project's FMUs in-process with fmpy.

Used by the FMU tests and benchmarks (and any Python master that drives the
FMU directly): start an initialised Co-Simulation instance and capture its log.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

from fmpy import calloc, free, read_model_description
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)

LogSink = Callable[[int, str], None]  # (fmi2Status, message)


def log_callbacks(sink: LogSink) -> fmi2CallbackFunctions:
    """FMI callbacks that pass every log message (status, text) to ``sink``.

    Keep the returned object alive as long as the instance lives.
    """

    def logger(_env, _instance, status, _category, message) -> None:
        sink(int(status), message.decode("utf-8", "replace").replace("%%", "%"))

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    return callbacks


def start_slave(
    unzip_dir: Path,
    instance_name: str,
    start_values: Mapping[str, float | str] | None = None,
    log: LogSink | None = None,
    start_time: float = 0.0,
    logging: bool | None = None,
) -> tuple[FMU2Slave, dict[str, int]]:
    """Instantiate and initialise an extracted FMU; return it and its name→valueReference map.

    ``logging`` is the instance's loggingOn (default: on when ``log`` is given);
    error messages reach ``log`` either way. A bad parameter raises fmpy's
    FMICallException (fmi2Error) from exitInitializationMode, with the message in
    ``log``.
    """
    md = read_model_description(str(unzip_dir))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=str(unzip_dir),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName=instance_name,
    )
    callbacks = None if log is None else log_callbacks(log)
    slave.instantiate(callbacks=callbacks,
                      loggingOn=log is not None if logging is None else logging)
    slave.setupExperiment(startTime=start_time)
    slave.enterInitializationMode()
    for name, value in (start_values or {}).items():
        if isinstance(value, str):
            slave.setString([refs[name]], [value])
        else:
            slave.setReal([refs[name]], [value])
    slave.exitInitializationMode()
    return slave, refs
