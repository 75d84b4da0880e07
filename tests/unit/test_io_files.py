"""save_figure (cvsflow.io.files): constrained-layout figures keep their size, others are cropped."""

from matplotlib.figure import Figure
from PIL import Image

from cvsflow.io import save_figure


def test_constrained_figure_is_saved_at_its_own_size(tmp_path):
    fig = Figure(figsize=(4.0, 3.0), layout="constrained")
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1])
    ax.set_xlabel("x (m)")
    save_figure(fig, tmp_path / "c.png", dpi=50)
    assert Image.open(tmp_path / "c.png").size == (200, 150)


def test_other_figures_are_cropped_to_what_is_drawn(tmp_path):
    fig = Figure(figsize=(4.0, 3.0))
    fig.text(0.4, 0.5, "only this")
    save_figure(fig, tmp_path / "t.png", dpi=50)
    w, h = Image.open(tmp_path / "t.png").size
    assert w < 150 and h < 40
