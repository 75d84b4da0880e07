"""save_figure (cvsflow.io.files): constrained-layout figures keep their size, others are cropped;
draw_figure draws only the figures a job declares."""

from matplotlib.figure import Figure
from PIL import Image

from cvsflow.io.files import draw_figure, save_figure


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


def test_draw_figure_draws_only_a_declared_figure(tmp_path):
    """With `figures: false` a rule declares no figure: the figure is neither drawn nor saved."""
    drawn = []

    def make():
        drawn.append(1)
        fig = Figure(figsize=(2.0, 2.0), layout="constrained")
        fig.subplots().plot([0, 1], [0, 1])
        return fig

    assert draw_figure({"fig": str(tmp_path / "f.png")}, "fig", make)
    assert (tmp_path / "f.png").is_file() and drawn == [1]
    assert not draw_figure({}, "fig", make)
    assert drawn == [1]


def test_read_csv_table_names_the_file_and_the_missing_columns(tmp_path):
    import pytest

    from cvsflow.exceptions import InputError
    from cvsflow.io.files import read_csv_table

    path = tmp_path / "scaling.csv"
    with pytest.raises(InputError, match="scaling.csv: file not found"):
        read_csv_table(path)
    path.write_text("stage,s\ncorners,1.5\n")
    assert read_csv_table(path, ["stage"])["s"].tolist() == [1.5]
    with pytest.raises(InputError, match=r"scaling.csv: missing columns \['cpu_s'\]"):
        read_csv_table(path, ["stage", "cpu_s"])
    path.write_text("stage,s\n")
    with pytest.raises(InputError, match="no rows"):
        read_csv_table(path)
