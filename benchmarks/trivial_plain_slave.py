"""A plain pythonfmu slave (no toggle code, no FMI guard): the Python reference of
benchmarks/bench_native_fmu.py, y = gain u and x = integral of u, built by pythonfmu alone."""

from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Real


class TrivialPlain(Fmi2Slave):
    """y = gain * u and x = integral of u, updated at the end of each step."""

    description = "Plain pythonfmu trivial slave (benchmark reference)"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-3)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.gain, self.u, self.y, self.x = 2.0, 0.0, 0.0, 0.0
        self.register_variable(Real("gain", causality=Fmi2Causality.parameter,
                                    variability="fixed"))
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        self.register_variable(Real("x", causality=Fmi2Causality.output))

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.x += self.u * step_size
        self.y = self.gain * self.u
        return True
