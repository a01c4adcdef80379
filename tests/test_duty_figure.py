"""``toggle plan --duty-plot``'s figure (toggle_cli.plan.duty_figure): the cycle fills the
torque-speed plane whatever the motor's size, and no legend lies over the curves."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.duty import Duty
from controllers.limits import drive_limits
from toggle.params import load_preset
from toggle_cli.plan_figures import DUTY_FILL, duty_figure


@pytest.mark.parametrize("peak", [0.05, 0.6, 2.0])  # N m: a tiny cycle, a fair one, too much
def test_the_cycle_fills_the_plane_and_the_legends_leave_the_axes_free(peak: float) -> None:
    from toggle.plots import plt

    mech = load_preset("chang2021")
    limits = drive_limits(mech)
    t = np.linspace(0.0, 2.0, 2001)
    duty = Duty(t, peak * np.sin(2 * np.pi * t), 40.0 * np.cos(2 * np.pi * t), mech.drive)
    fig = duty_figure(duty, limits, mech.drive.rated_torque, "test")
    try:
        fig.canvas.draw()
        ax_t, ax_c = fig.axes[:2]
        low, high = ax_c.get_ylim()
        assert low == 0 and peak <= high <= 1.15 * peak / DUTY_FILL + 1e-12
        assert ax_c.get_xlim()[1] == pytest.approx(1.15 * 40.0)
        renderer = fig.canvas.get_renderer()
        for ax in (ax_t, ax_c):
            legend = ax.get_legend().get_window_extent(renderer)
            assert not legend.overlaps(ax.get_window_extent(renderer))
        said = next(text.get_text() for text in ax_c.texts)
        usable = float(np.max(np.abs(duty.torque) / limits.torque_at(np.abs(duty.speed))))
        assert said.startswith(f"peak {usable:.0%} of the usable torque")
        assert f"RMS {duty.rms_torque / mech.drive.rated_torque:.0%} of the rated" in said
    finally:
        plt.close(fig)
