"""Every figure the project ships fits a laptop screen: no PNG under results/ or docs/results/ is wider
than 1600 px (issue #48). Redraw one from its JSON with the bench's ``--replot`` (or the ``replot``
functions of experiments/figures.py and experiments/plans_figures.py)."""

from __future__ import annotations

from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
MAX_WIDTH_PX = 1600
SHIPPED = (ROOT / "results", ROOT / "docs" / "results")


def too_wide(folders: tuple[Path, ...], max_px: int = MAX_WIDTH_PX) -> dict[str, int]:
    """Each PNG under ``folders`` wider than ``max_px``, with its width (PIL reads the header only)."""
    wide = {}
    for folder in folders:
        for png in sorted(folder.rglob("*.png")):
            with Image.open(png) as im:
                if im.width > max_px:
                    wide[str(png.relative_to(folder.parent))] = im.width
    return wide


def test_no_shipped_figure_is_wider_than_a_laptop_screen():
    assert any(any(f.rglob("*.png")) for f in SHIPPED), "no figure found: the check would pass vacuously"
    assert too_wide(SHIPPED) == {}


def test_a_too_wide_figure_is_flagged(tmp_path: Path):
    (tmp_path / "sub").mkdir()
    Image.new("RGB", (MAX_WIDTH_PX + 1, 10)).save(tmp_path / "sub" / "wide.png")
    Image.new("RGB", (MAX_WIDTH_PX, 10)).save(tmp_path / "fits.png")
    assert too_wide((tmp_path,)) == {f"{tmp_path.name}/sub/wide.png": MAX_WIDTH_PX + 1}
