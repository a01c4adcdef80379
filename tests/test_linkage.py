"""The mechanism drawn to scale (toggle.linkage, ``toggle plot linkage``): the joints drawn
are the kinematics' joints, every link keeps its length, the halves mirror, the GIF has the
frames asked for."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from toggle.kinematics import clamp_joints, half_joints, half_pose
from toggle.linkage import JOINTS_GID, animate_linkage, draw_linkage, stroke_ends
from toggle.params import load_preset
from toggle.plots import plt
from toggle_cli import main

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("chang2021", "lin2003_sm55", str(ROOT / "design/examples/sm55_design.toml"))


@pytest.mark.parametrize("name", PRESETS)
def test_every_link_keeps_its_length_over_the_stroke(name: str) -> None:
    mech = load_preset(name)
    xs = np.linspace(*stroke_ends(mech), 31)
    for dims in (mech.lower, mech.upper):
        j = half_joints(xs, dims)

        def dist(a: tuple, b: tuple) -> np.ndarray:
            return np.hypot(a[0] - b[0], a[1] - b[1])
        for (a, b), length in (((j.crosshead, j.corner), dims.r3), ((j.pivot, j.corner), dims.r4a),
                               ((j.pivot, j.elbow), dims.r4b), ((j.corner, j.elbow), dims.r4c),
                               ((j.elbow, j.platen), dims.r5)):
            np.testing.assert_allclose(dist(a, b), length, rtol=0, atol=1e-12)
        np.testing.assert_allclose(j.platen[0], half_pose(xs, dims).L, atol=1e-12)
        np.testing.assert_allclose(j.platen[1], dims.e, atol=1e-12)
        np.testing.assert_allclose(j.crosshead[1] - j.pivot[1], dims.r1 - dims.r2, atol=1e-15)


def test_at_the_toggle_pivot_elbow_and_platen_joint_are_collinear() -> None:
    """Seed 000, Figure 3c: A, B, C and D, E, F on one line at the toggle."""
    mech = load_preset("chang2021")
    x_tp = stroke_ends(mech)[1]
    for j in clamp_joints(x_tp, mech.lower, mech.upper).values():
        (px, py), (ex, ey), (fx, fy) = j.pivot, j.elbow, j.platen
        cross = (ex - px) * (fy - py) - (ey - py) * (fx - px)
        assert abs(float(cross)) < 1e-12


def test_a_symmetric_clamp_draws_mirrored_halves_and_an_error_breaks_the_mirror() -> None:
    mech = load_preset("chang2021")
    x = 0.02
    joints = clamp_joints(x, mech.lower, mech.upper)
    for low, up in zip(joints["lower"], joints["upper"]):
        assert float(low[0]) == pytest.approx(float(up[0]), abs=1e-15)
        assert float(low[1]) == pytest.approx(-float(up[1]), abs=1e-15)
    bent = mech.with_error("upper", "r5", 0.5e-3)
    joints = clamp_joints(x, bent.lower, bent.upper)
    assert float(joints["upper"].platen[0]) - float(joints["lower"].platen[0]) \
        == pytest.approx(0.5e-3, rel=0.1)


@pytest.mark.parametrize("name", PRESETS)
def test_the_joints_drawn_are_the_kinematics_joints(name: str) -> None:
    mech = load_preset(name)
    x = float(np.mean(stroke_ends(mech)))
    fig, ax = plt.subplots()
    try:
        draw_linkage(ax, mech, x)
        (marks,) = [line for line in ax.lines if line.get_gid() == JOINTS_GID]
        drawn = np.column_stack(marks.get_data())
    finally:
        plt.close(fig)
    expected = [(float(p[0]), float(p[1])) for j in clamp_joints(x, mech.lower, mech.upper).values()
                for p in j]
    np.testing.assert_allclose(drawn, np.array(expected) * 1e3, atol=1e-9)


def test_the_animation_has_the_frames_asked_for_and_one_size(tmp_path: Path) -> None:
    mech = load_preset("chang2021")
    path = animate_linkage(mech, tmp_path / "linkage.gif", frames=6)
    with Image.open(path) as gif:
        sizes = set()
        for i in range(gif.n_frames):
            gif.seek(i)
            sizes.add(gif.size)
        assert gif.n_frames == 6
    assert len(sizes) == 1
    width, height = sizes.pop()
    assert width > 300 and height > 200


def test_plot_linkage_writes_the_figure_and_the_animation(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture) -> None:
    assert main(["plot", "linkage", "--preset", "lin2003_sm55", "--out", str(tmp_path),
                 "--animate", "--frames", "3"]) == 0
    printed = capsys.readouterr().out
    names = ("linkage_lin2003_sm55.png", "linkage_lin2003_sm55.gif")  # the preset in the name
    assert printed == f"results in {tmp_path}/ ({', '.join(names)})\n"
    assert all((tmp_path / name).stat().st_size > 1000 for name in names)


def test_a_position_where_the_clamp_cannot_assemble_is_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["plot", "linkage", "--x", "0.5", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "cannot assemble at x = 0.5 m" in err and "\n" not in err
    assert not list(tmp_path.iterdir())
