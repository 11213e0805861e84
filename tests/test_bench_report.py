"""The HTML report a person reads: goal banner first, readable tables with units, every image embedded."""

import base64
import io
import re
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest
import yaml
from PIL import Image

from benchmarks import registry, summary
from benchmarks.report import column_label, goal_banner, plot_area_errors, plot_rop_vs_distance, write_html
from benchmarks.runner import execute
from benchmarks.store import Store
from benchmarks.suite import load_suite

SUITE = {"name": "tiny-report", "cases": [
    {"name": "leaf-{distance_m}m", "scene": {"generator": "plate-leaf"}, "vary": {"distance_m": [3.0, 5.0]}},
    {"name": "edge", "scene": {"builtin": "knife-edge"}, "targets": ["plate"]},
]}


def _row(variant, family, **values):
    row = {key: None for key in summary.SUMMARY_KEYS}
    return {**row, "suite": "s", "variant": variant, "family": family, **values}


def test_goal_banner_says_met_not_met_and_not_measured():
    table = [_row("raw", "raw", rop_reduction=0.0, area_rel_err_median=0.3),
             _row("buffer", "prop-sfs", rop_reduction=0.95, area_rel_err_median=0.08),
             _row("fused", "prop-sfs", rop_reduction=0.92, area_rel_err_median=0.03),
             _row("step", "woody", diameter_err_median_m=0.012)]
    goals = goal_banner([], table)
    project, canopy, step, cylinders = goals
    assert project["status"] == "met" and project["measured"].startswith("fused: ROP red. 92%")
    assert canopy["status"] == "not measured", "no canopy case in the run"
    assert step["status"] == "not met" and "0.0120 m ✗" in step["measured"]
    assert cylinders["status"] == "not measured"
    table[2]["area_rel_err_median"] = 0.06  # neither meets both: the best first check is named, its miss marked
    project = goal_banner([], table)[0]
    assert project["status"] == "not met" and project["measured"].startswith("buffer: ROP red. 95%, median |area err| 8.0% ✗")


def test_every_table_column_has_a_title_and_a_unit():
    text = {"suite", "variant", "family", "scene", "case", "group"}
    keys = set(summary.SUMMARY_KEYS) | set(summary.VALIDATION_KEYS) | set(summary.RPPP_KEYS) | set(summary.CASE_KEYS)
    for key in keys - text:
        title, unit = column_label(key)
        assert unit and "_" not in title, (key, title, unit)
    assert column_label("rop_after:fused") == ("ROP after, fused", "%")
    assert column_label("points_per_cm2") == ("point density", "points/cm²")


def test_missed_leaves_are_counted_not_drawn_at_minus_100_percent():
    leaves = [{"variant": "fused", "case": "c", "area_true_m2": 0.004, "visibility": 1.0, "area_m2": a,
               "area_rel_err": a / 0.004 - 1, "found": int(a > 0)} for a in (0.0041, 0.0039, 0.0)]
    figure = plot_area_errors(leaves)
    axes = figure.axes[0]
    assert [t.get_text() for t in axes.texts] == ["2 found / 1 missed"]
    whiskers = np.concatenate([line.get_xdata() for line in axes.lines if len(line.get_xdata()) == 2])
    assert whiskers.min() > -5, "the missed leaf's -100 % is not in the box plot"


def test_rop_against_distance_never_joins_different_scenes():
    leaves = [{"variant": "raw", "case": case, "object_type": "leaf", "range_m": r, "rop_after": 0.2}
              for case, r in (("a1", 1.0), ("a2", 3.0), ("b", 2.0))]
    figure = plot_rop_vs_distance(leaves, {"a1": "single-leaf", "a2": "single-leaf", "b": "leafy-tree"})
    assert [axes.get_title() for axes in figure.axes] == ["single-leaf", "leafy-tree"]
    assert [len(axes.lines[0].get_xdata()) for axes in figure.axes] == [2, 1]


class _Page(HTMLParser):
    """Collects the page's images, external references, table headers and the text before the first image."""

    def __init__(self):
        super().__init__()
        self.images, self.external, self.headers, self.text, self._th = [], [], [], [], None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs.get("src", ""))
        for name in ("src", "href"):
            if name in attrs and tag != "img":
                self.external.append(attrs[name])
        if tag in ("link", "script", "iframe", "object", "embed"):
            self.external.append(tag)
        if tag == "th":
            self._th = ""

    def handle_endtag(self, tag):
        if tag == "th":
            self.headers.append(self._th)
            self._th = None

    def handle_data(self, data):
        if self._th is not None:
            self._th += data
        if not self.images:
            self.text.append(data)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The report of a tiny run with a filter and the raw scan: (html path, text)."""
    root = tmp_path_factory.mktemp("report")
    (root / "suite.yaml").write_text(yaml.safe_dump(SUITE))
    with Store(root / "r.sqlite") as store:
        outcome = execute(load_suite(str(root / "suite.yaml")), registry.resolve(["raw", "shadow"]), store,
                          workers=0, progress=False)
        path = write_html(store, outcome.run_id, root / "report.html")
    return path, path.read_text()


def test_report_opens_on_the_goal_banner_and_has_units_in_every_header(report):
    _, text = report
    page = _Page()
    page.feed(text)
    first_screen = " ".join(page.text)
    assert "Goals" in first_screen and "PROP-SFS variant with ROP reduction ≥ 90%" in first_screen
    assert "not measured" in first_screen, "a run without PROP-SFS variants says so"
    assert text.index("<h2>Goals</h2>") < text.index("<h2>Headline</h2>") < text.index("<h2>Per-case pictures</h2>")
    assert not re.search(r">\s*(rop_after|area_rel_err_median|good_points_lost)\s*<", text), "raw column names"
    numeric = [h for h in page.headers if h not in ("variant", "suite", "family", "scene", "case", "leaf group",
                                                     "status", "goal of", "goal", "swept value")
               and not h.startswith("this run")]
    assert numeric and all(re.search(r"\([^()]+\)$", h) for h in numeric), [h for h in numeric
                                                                          if not re.search(r"\([^()]+\)$", h)]


def test_report_is_one_file_with_every_image_embedded_and_decodable(report):
    _, text = report
    page = _Page()
    page.feed(text)
    assert page.external == [], "the report references files or scripts outside itself"
    assert len(page.images) >= 5  # the goal figure, before/after, the three cases' pictures, ...
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        image = Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1])))
        image.load()
        pixels = np.asarray(image.convert("L"))
        assert min(pixels.shape) > 50 and pixels.std() > 5, "an empty picture"


@pytest.mark.skipif(shutil.which("chromium-headless-shell") is None and shutil.which("chromium") is None,
                    reason="no headless Chromium on this machine")
def test_report_renders_in_headless_chromium(report, tmp_path):
    path, _ = report
    browser = shutil.which("chromium-headless-shell") or shutil.which("chromium")
    shot = tmp_path / "shot.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,1000",
                    f"--screenshot={shot}", path.as_uri()], capture_output=True, timeout=120, check=True)
    pixels = np.asarray(Image.open(shot).convert("L"))
    assert pixels.shape == (1000, 1400) and (pixels < 128).mean() > 0.01, "the first screen is blank"


def test_case_pictures_of_large_scans_are_coarsened(llvm):
    from benchmarks.report import preview_case

    spec = {"name": "edge", "scene": {"builtin": "knife-edge"}, "scanner": {}, "seed": 0}
    _, _, full, n_pulses = preview_case(spec, max_pulses=10**6)
    assert full.shape[0] * full.shape[1] == n_pulses > 1000
    _, _, small, same = preview_case(spec, max_pulses=n_pulses // 4)
    assert same == n_pulses and n_pulses // 6 <= small.shape[0] * small.shape[1] <= n_pulses // 4


def test_a_tree_case_gets_one_before_after_figure_with_fewer_outliers_after(tmp_path):
    # The eight-leaf twig is the smallest scene scored on the whole scan; at 0.04 deg it is 168 x 305 pulses.
    suite = {"name": "tiny-tree", "cases": [{"name": "cluster", "scene": {"builtin": "leaf-cluster"},
                                             "scanner": {"step_deg": 0.04}}]}
    (tmp_path / "suite.yaml").write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(tmp_path / "suite.yaml")), registry.resolve(["raw", "fused"]), store,
                          workers=0, progress=False)
        text = write_html(store, outcome.run_id, tmp_path / "report.html").read_text()
    assert text.count("<h3>Before / after on a tree</h3>") == 1
    page = _Page()
    page.feed(text.split("<h3>Before / after on a tree</h3>", 1)[1])
    pixels = np.asarray(Image.open(io.BytesIO(base64.b64decode(page.images[0].split(",", 1)[1]))).convert("RGB"))
    pixels = pixels.astype(int)
    red = (pixels[..., 0] > 180) & (pixels[..., 1] < 80) & (pixels[..., 2] < 80)
    half = pixels.shape[1] // 2
    before, after = int(red[:, :half].sum()), int(red[:, half:].sum())
    assert before > 500 and after < before / 4, (before, after)


def test_a_run_of_a_variant_no_longer_registered_still_reports(tmp_path):
    suite = {"name": "retired", "cases": [SUITE["cases"][1]]}
    (tmp_path / "suite.yaml").write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(tmp_path / "suite.yaml")), registry.resolve(["raw", "shadow"]), store,
                          workers=0, progress=False)
        store._db.execute("UPDATE results SET variant = 'retired-filter' WHERE variant = 'shadow'")
        text = write_html(store, outcome.run_id, tmp_path / "report.html").read_text()
    assert "retired-filter" in text and "<h3>Before / after on one leaf</h3>" in text


def test_a_run_of_height_fields_only_reports_without_case_pictures(tmp_path):
    # A height-field case has no scene to scan: it gets no range/intensity preview, and the page is still written.
    suite = {"name": "heights", "cases": [{"name": "dome", "scene": {"heightfield": "hemisphere", "side": 25}}]}
    (tmp_path / "suite.yaml").write_text(yaml.safe_dump(suite))
    with Store(tmp_path / "r.sqlite") as store:
        outcome = execute(load_suite(str(tmp_path / "suite.yaml")), registry.resolve(["buffer"]), store,
                          workers=0, progress=False)
        text = write_html(store, outcome.run_id, tmp_path / "report.html").read_text()
    assert "hemisphere" in text and "<figcaption>dome" not in text
