"""The report's interactive figures (hybridtwin.report.interactive and interactive_machine; issue 39, item 2).

(a) Each figure function's traces are named per run and probe (per mass's model sweep, per branch, per mode) and
carry the numbers the PNG draws, read here another way: the signals and whirl spectra from the harmonics (a sum of
cosines, an FFT), the Bode and polar points from the harmonics and the dense table, the Campbell branches from the
model's eigenvalues, the mode shapes from the undamped modes, the summary from the error tables, the diagnosis from
its table. Seconds, no solver but the eigenvalues.

(b) In a real headless Chromium, each figure's HTML file, written by ``interactive.write_html``, renders (plotly's
SVG, every visible trace drawn) and answers a mouse moved over a data point (a ``mousemove`` at the point's pixel,
computed in the page from the subplot's axes, dispatched to the element under it: plotly's drag layer) with a hover
label that gives the point's value and unit; in the comparison per run and the Bode figure, a click on a legend
entry (mouse down and up) shows or hides that run's (probe's) traces and no other; the check itself fails on a
figure whose hover is switched off. A small script injected into a copy of the file writes its findings into
<pre id="result">, read from ``chromium --dump-dom``. The same check on the report's page of all figures
(``interactive_pages.write_gallery``: plotly.js once), each figure chosen by the URL's fragment: the same
interactivity there. Skipped, saying why, where /usr/bin/chromium is absent; .ci/run installs it and runs this
file. About two minutes (a browser start per figure and page).

(c) The pages read back their figures exactly, and the gallery holds plotly.js once; both packed (gzip, base64:
``interactive_pages.pack``), read back here with Python's gzip, drawn in the browser by its DecompressionStream.
"""

from __future__ import annotations

import base64
import gzip
import html
import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import plotly.io as pio
import pytest
from matplotlib.colors import to_hex
from scipy import stats

from example_machines import stepped_machine
from hybridtwin.diagnose.conclusion import Diagnosis
from hybridtwin.diagnose.diagnosis_status import VERDICT_COLOUR, CandidateVerdict
from hybridtwin.model.model import Model, campbell
from hybridtwin.report import interactive as ia
from hybridtwin.report import interactive_pages as pages
from hybridtwin.report import interactive_machine as im
from hybridtwin.report import report, summary
from hybridtwin.report import response_plots as rp
from hybridtwin.report.machine_plots import undamped_modes
from hybridtwin.report.report import RunComparison

CHROMIUM = Path("/usr/bin/chromium")
H = 3
MASSES = (20.0, 10.0)
RUN_RPM = (600.0, 900.0, 1200.0)
SIGMA = 1e-6  # [m], each real and imaginary part
#: the dense grid: 20 RPM steps that miss the run speeds (a run's point is the closest to its own pixel)
GRID = np.arange(510.0, 1300.0, 20.0)
#: the run-down's jump band (its 1X at 0.7 of the run-up's) and the unstable stretch inside it
JUMP, UNSTABLE = (1000.0, 1100.0), (1000.0, 1060.0)


def _one_mode(rpm: float, mass_g: float) -> complex:
    """The x probe's 1X [m] of a one-mode rotor (critical speed 900 RPM, 5 % damping), y = -i x (forward)."""
    r = rpm / 900.0
    return 1e-3 * mass_g / 20.0 * r**2 / (1 - r**2 + 0.1j * r)


def _harmonics(rpm: float, mass_g: float) -> np.ndarray:
    Z = np.zeros((H, 2), complex)
    x = _one_mode(rpm, mass_g)
    Z[0] = [x, -1j * x]
    Z[2] = 1e-5 * np.array([1.0 + 0.5j, 0.3j])  # a small 3X
    return Z


@pytest.fixture(scope="module")
def comparisons():
    """Six fit runs (two masses, three speeds; measured = model + noise of SIGMA) and a validation run measured 10 %
    above its prediction (the worst run)."""
    rng = np.random.default_rng(7)
    out = []
    for mass in MASSES:
        for rpm in RUN_RPM:
            M = _harmonics(rpm, mass)
            X = M + SIGMA * (rng.standard_normal((H, 2)) + 1j * rng.standard_normal((H, 2)))
            out.append(RunComparison(f"r{rpm:.0f}_m{mass:g}", "fit", rpm, mass, X, M, np.full((H, 2), SIGMA),
                                     2 * 2 * H - 1.0, "solver"))
    M = _harmonics(800.0, 15.0)
    out.append(RunComparison("v", "validate", 800.0, 15.0, 1.1 * M, M, np.full((H, 2), SIGMA), 2 * 2 * H - 1.0,
                             "solver"))
    return out


@pytest.fixture(scope="module")
def dense(tmp_path_factory):
    """A dense table (response_plots.columns) by hand: per mass a run-up and a run-down, the run-down 0.7 of the
    run-up in the jump band and unstable in part of it; written and read back by the table's own writer and reader."""
    rows = []
    for mass in MASSES:
        for sweep in ("run-up", "run-down"):
            for rpm in GRID:
                jump = sweep == "run-down" and JUMP[0] <= rpm <= JUMP[1]
                Z = _harmonics(rpm, mass) * (0.7 if jump else 1.0)
                stable = not (sweep == "run-down" and UNSTABLE[0] <= rpm <= UNSTABLE[1])
                for h in range(1, H + 1):
                    rows.append((mass, 0.0, sweep, rpm, h, Z[h - 1, 0].real, Z[h - 1, 0].imag, Z[h - 1, 1].real,
                                 Z[h - 1, 1].imag, stable, "0"))
    path = tmp_path_factory.mktemp("dense") / "response.tsv"
    rp.write_dense(pd.DataFrame(rows, columns=rp.columns(("x", "y"))), path)
    return rp.read_dense(path)


@pytest.fixture(scope="module")
def rotor():
    """The stepped rotor with its two linear bearings and the disks' gyroscopic moments, at nominal values: forward
    and backward branches apart, damped (log decrements), disks, bearings and a probe pair to mark."""
    machine = stepped_machine()
    fx = machine.effects()
    model = Model([fx["linear_bearing@a"], fx["linear_bearing@b"], fx["gyroscopic"]], machine)
    return model, {k: p.nominal for k, p in model.parameters.items()}


def _errors(comparisons, scale: float = 1.0) -> pd.DataFrame:
    table = report.error_table(comparisons)
    table[["chi2", "chi2_dof"]] *= scale
    table["beyond_noise"] = stats.chi2.sf(table["chi2"], table["dof"]) < report.ALPHA
    return table


@pytest.fixture(scope="module")
def ledger_errors(comparisons):
    errors = {"base": _errors(comparisons, 30.0), "base_slope": _errors(comparisons)}
    rows = [report.ledger_row(name, "", {"n_data": 84, "dof": 70, "chi2": float(table["chi2"].sum())}, table)
            for name, table in errors.items()]
    return report.ledger_table(rows), errors


@pytest.fixture(scope="module")
def diagnosis():
    table = pd.DataFrame({"effect": ["slope_spring", "excitation_3x", "moment_stiffness"],
                          "statistic": [500.0, 20.0, 0.5], "dof": [1, 2, 1], "p_value": [1e-100, 1e-4, 0.5],
                          "predicted_chi2_dof": [1.1, 3.0, 4.0], "confirmed_chi2_dof": [1.05, np.nan, np.nan],
                          "verdict": ["add: explains the discrepancy", "not confirmed", "not significant"],
                          "verdict_code": [CandidateVerdict.ADD.value, CandidateVerdict.NOT_CONFIRMED.value,
                                           CandidateVerdict.NOT_SIGNIFICANT.value]})
    return Diagnosis(table, "add slope_spring", "", {"variant": "geometric", "alpha_per_candidate": 0.01 / 3,
                                                     "base_chi2_dof": 4.2})


def _axes(fig, row: int, col: int) -> tuple[str, str]:
    """The trace-side axis ids ("x3", "y3") of a cartesian subplot."""
    sub = fig.get_subplot(row, col)
    return sub.xaxis.plotly_name.replace("axis", ""), sub.yaxis.plotly_name.replace("axis", "")


def _traces(fig, row: int, col: int, name: str | None = None, kind: str | None = None) -> list:
    x, y = _axes(fig, row, col)
    return [t for t in fig.data if t.xaxis == x and t.yaxis == y and (name is None or t.name == name)
            and (kind is None or t.type == kind)]


def _polar(fig, row: int, col: int, name: str) -> list:
    subplot = fig.get_subplot(row, col).plotly_name
    return [t for t in fig.data if t.type == "scatterpolar" and t.subplot == subplot and t.name == name]


# --- (a) the figures' numbers ----------------------------------------------------------------------------------


def test_comparison_per_run_has_a_group_per_run_and_probe_with_the_runs_signals(comparisons):
    fig = ia.runs_figure(comparisons, "demo")
    groups = {t.legendgroup for t in fig.data}
    for c in comparisons:
        assert {f"{c.run}: x", f"{c.run}: y", f"{c.run}: orbit, whirl (x, y)"} <= groups
        for j, channel in enumerate(("x", "y")):
            measured, model = _traces(fig, 1, 2, f"{c.run}: {channel}")[:2]
            theta = 2 * np.pi * np.asarray(measured.x)
            wave = lambda Z: sum((Z[h, j] * np.exp(1j * (h + 1) * theta)).real for h in range(H))  # noqa: E731
            np.testing.assert_allclose(measured.y, 1e3 * wave(c.measured), rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(model.y, 1e3 * wave(c.model), rtol=1e-12, atol=1e-12)
            residual = _traces(fig, 2, 2, f"{c.run}: {channel}", "scatter")[0]
            np.testing.assert_allclose(residual.y, 1e6 * (wave(c.measured) - wave(c.model)), atol=1e-9)
        # the whirl spectrum: z = x + i y over a revolution, its FFT: bin h forward, bin -h backward
        theta = 2 * np.pi * np.arange(64) / 64
        bars = {t.offsetgroup: np.asarray(t.y) for t in _traces(fig, 1, 3, f"{c.run}: orbit, whirl (x, y)", "bar")}
        for Z, key in ((c.measured, "measured"), (c.model, "model"), (c.measured - c.model, "residual")):
            z = sum(Z[h, 0] * np.exp(1j * (h + 1) * theta) for h in range(H)).real \
                + 1j * sum(Z[h, 1] * np.exp(1j * (h + 1) * theta) for h in range(H)).real
            spectrum = np.fft.fft(z) / 64
            expected = np.abs(spectrum[[-3, -2, -1, 1, 2, 3]]) * 1e6
            np.testing.assert_allclose(bars[key], expected, rtol=1e-9, atol=1e-9)
    # the worst run shown, the others a click away
    worst = max(comparisons, key=lambda c: c.chi2_dof).run
    assert worst == "v"
    assert {t.visible for t in fig.data if t.legendgroup.startswith("v: ")} == {True}
    assert {t.visible for t in fig.data if not t.legendgroup.startswith("v: ")} == {"legendonly"}


def test_comparison_per_run_draws_a_row_per_plane_of_probes():
    """A machine with two probe planes (x1, y1 and x2, y2, in another order on record): a row of panels per plane,
    a legend entry per probe, each plane's orbit its own channels, taken by name."""
    rng = np.random.default_rng(3)
    X = 1e-4 * (rng.standard_normal((H, 4)) + 1j * rng.standard_normal((H, 4)))
    c = RunComparison("r1", "fit", 700.0, 10.0, X, 0.9 * X, np.full((H, 4), SIGMA), 20.0, "solver",
                      ("x1", "x2", "y1", "y2"))
    fig = ia.runs_figure([c], "two planes", [("x1", "y1"), ("x2", "y2")])
    assert {t.legendgroup for t in fig.data} == {"r1: x1", "r1: y1", "r1: x2", "r1: y2", "r1: orbit, whirl (x1, y1)",
                                                  "r1: orbit, whirl (x2, y2)"}
    for row, (x_name, y_name) in ((1, ("x1", "y1")), (3, ("x2", "y2"))):
        orbit = _traces(fig, row, 1, f"r1: orbit, whirl ({x_name}, {y_name})")[0]  # measured, over one revolution
        theta = 2 * np.pi * np.asarray(orbit.customdata)  # each point's revolution, as its hover says
        assert theta.size > 100 and theta[0] == 0.0 and theta[-1] == 2 * np.pi  # a smooth, closed orbit
        for values, name in ((orbit.x, x_name), (orbit.y, y_name)):
            j = c.channels.index(name)
            expected = sum((X[h, j] * np.exp(1j * (h + 1) * theta)).real for h in range(H))
            np.testing.assert_allclose(values, 1e3 * expected, atol=1e-12)
        assert {t.name for t in _traces(fig, row, 2)} == {f"r1: {x_name}", f"r1: {y_name}"}


def test_bode_draws_the_dense_table_and_each_runs_point(dense, comparisons):
    fig = ia.bode_figure(dense, comparisons, "demo")
    for mass in MASSES:
        for sweep in ("run-up", "run-down"):
            part = dense[(dense.harmonic == 1) & (dense.eccentric_mass_g == mass) & (dense.sweep == sweep)]
            z = (part["x_re_m"] + 1j * part["x_im_m"]).to_numpy()
            stable = part["stable"].to_numpy(bool)
            lines = _traces(fig, 1, 1, f"{mass:g} g model, {sweep}")  # amplitude, then its unstable stretch
            np.testing.assert_array_equal(lines[0].x, part["rpm"])
            np.testing.assert_allclose(lines[0].y, np.where(stable, np.abs(z) * 1e6, np.nan), rtol=1e-12)
            np.testing.assert_allclose(lines[0].customdata, np.abs(z) * 1e6, rtol=1e-12)  # the hover's value
            if not stable.all():
                assert lines[1].line.dash == "dot"
                np.testing.assert_allclose(lines[1].y, np.where(stable, np.nan, np.abs(z) * 1e6), rtol=1e-12)
            phase = _traces(fig, 2, 1, f"{mass:g} g model, {sweep}")[0]
            ok = np.isfinite(np.asarray(phase.y, float))
            assert ok.sum() == stable.sum()
            np.testing.assert_allclose(np.exp(1j * np.radians(np.asarray(phase.y, float)[ok])),
                                       (z / np.abs(z))[ok], atol=1e-9)
    for c in comparisons:
        for h, col in ((1, 1), (3, 3)):
            for j in (0, 1):
                X = c.measured[h - 1, j]
                (amp,) = [t for t in _traces(fig, 2 * j + 1, col) if t.name.split(" ")[0] == c.run][:1]
                assert amp.y[0] == pytest.approx(abs(X) * 1e6, rel=1e-12)
                assert amp.x[0] == c.rpm
                if c.role == "fit":
                    assert amp.error_y.array[0] == pytest.approx(2 * SIGMA * 1e6)
                if c.role == "fit" and abs(X) > 2 * SIGMA:  # a phase is drawn above the noise only
                    phase = [t for t in _traces(fig, 2 * j + 2, col) if t.name.split(" ")[0] == c.run][0]
                    assert np.exp(1j * np.radians(phase.y[0])) == pytest.approx(X / abs(X), abs=1e-9)
    # a legend entry per run and per mass's sweep
    named = {t.name for t in fig.data if t.showlegend}
    assert {n.split(" ")[0] for n in named} >= {c.run for c in comparisons}
    assert {f"{m:g} g model, {s}" for m in MASSES for s in ("run-up", "run-down")} <= named


def test_polar_puts_each_run_at_its_measured_harmonic(dense, comparisons):
    fig = ia.polar_figure(dense, comparisons, "demo")
    for c in comparisons:
        for j in (0, 1):
            for col, h in enumerate((1, 2, 3), start=1):
                points = [t for t in _polar(fig, j + 1, col, next(t.name for t in fig.data
                                                                   if t.name.split(" ")[0] == c.run))]
                X = c.measured[h - 1, j]
                assert points[0].r[0] == pytest.approx(abs(X) * 1e6, rel=1e-12)
                assert points[0].theta[0] == pytest.approx(np.degrees(np.angle(X)), abs=1e-9)
                if c.role == "validate":  # and its prediction
                    assert points[1].r[0] == pytest.approx(abs(c.model[h - 1, j]) * 1e6, rel=1e-12)
    part = dense[(dense.harmonic == 1) & (dense.eccentric_mass_g == 20.0) & (dense.sweep == "run-up")]
    (curve,) = _polar(fig, 1, 1, "20 g model, run-up")
    np.testing.assert_allclose(curve.r, np.hypot(part["x_re_m"], part["x_im_m"]) * 1e6, rtol=1e-12)


def test_campbell_draws_the_models_branches_and_their_damping(rotor):
    model, values = rotor
    rpm = np.linspace(0.0, 20000.0, 41)
    fig = im.campbell_figure(model, values, rpm, run_rpm=[3000.0, 4000.0], n_modes=6)
    table = campbell(model, values, rpm, 12)
    forward = table[table.whirl == "forward"].sort_values(["rpm", "frequency_hz"]).groupby("rpm").first()
    frequency, decrement = [t for t in fig.data if t.name == "1F: forward whirl, branch 1"]
    np.testing.assert_array_equal(frequency.x, rpm)
    np.testing.assert_allclose(frequency.y, forward["frequency_hz"], rtol=1e-12)
    zeta = forward["damping_ratio"].to_numpy()
    np.testing.assert_allclose(decrement.y, 2 * np.pi * zeta / np.sqrt(1 - zeta**2), rtol=1e-9)
    assert frequency.yaxis != decrement.yaxis and frequency.legendgroup == decrement.legendgroup
    # the 1X crossing of the lowest forward branch, by interpolation here
    gap = forward["frequency_hz"].to_numpy() - rpm / 60.0
    i = int(np.flatnonzero(np.sign(gap[:-1]) != np.sign(gap[1:]))[0])
    crossing = rpm[i] + gap[i] / (gap[i] - gap[i + 1]) * (rpm[i + 1] - rpm[i])
    (critical,) = [t for t in fig.data if t.name == "critical speeds (1X)"]
    assert np.min(np.abs(np.asarray(critical.x) - crossing)) < 1e-6 * crossing
    assert {"1B: backward whirl, branch 1", "1X", "2X", "3X", "run speeds"} <= {t.name for t in fig.data}


def test_mode_shapes_are_the_undamped_modes_with_the_machine_marked(rotor):
    model, values = rotor
    fig = im.mode_shapes_figure(model, values, 3000.0, n_modes=4)
    modes = undamped_modes(model, values, 3000.0, n_modes=8)
    shapes = [t for t in fig.data if t.name.startswith("mode ") and t.mode == "lines"]
    assert len(shapes) == 4
    for k, trace in enumerate(shapes):
        assert trace.name.startswith(f"mode {k + 1}: {modes.frequency_hz[k]:.4g} Hz")
        assert np.max(np.abs(trace.y)) == pytest.approx(1.0)
    nodes = [t for t in fig.data if t.legendgroup == shapes[0].name and t.mode == "markers"][0]
    np.testing.assert_allclose(nodes.x, model.shaft.z)
    marks = {t.name: list(t.customdata) for t in fig.data if t.name in ("bearings", "disks", "probes")}
    assert marks["bearings"][:2] == ["bearing a (node 2)", "bearing b (node 13)"]
    assert marks["disks"][:2] == ["disk d1 (node 8)", "disk d2 (node 16)"]
    assert marks["probes"][:2] == ["probe x1 (node 8)", "probe y1 (node 8)"]


def test_summary_colours_each_run_by_its_error_and_says_beyond_the_noise(ledger_errors):
    ledger, errors = ledger_errors
    fig = ia.summary_figure(ledger, errors)
    (heatmap,) = [t for t in fig.data if t.type == "heatmap"]
    runs = summary.run_order(errors)
    for j, variant in enumerate(ledger["variant"]):
        table = errors[variant].set_index("run")
        for i, run in enumerate(runs["run"]):
            assert heatmap.z[i][j] == pytest.approx(np.log10(max(table.at[run, "chi2_dof"], 0.1)))
            said = heatmap.customdata[i][j]
            assert run in said and variant in said
            assert ("beyond the noise" in said) == bool(table.at[run, "beyond_noise"])
            assert heatmap.text[i][j].startswith("<b>") == bool(table.at[run, "beyond_noise"])
    (fit,) = [t for t in fig.data if t.name == "fit runs"]
    np.testing.assert_allclose(fit.y, ledger["chi2_dof"])


def test_diagnosis_shows_each_candidates_score_against_its_threshold(diagnosis):
    fig = ia.diagnosis_figure(diagnosis)
    table = diagnosis.table.iloc[::-1]
    (bars,) = [t for t in fig.data if t.type == "bar"]
    assert list(bars.y) == list(table["effect"])
    np.testing.assert_allclose(bars.x, table["statistic"])
    assert bars.marker.color[-1] == to_hex(VERDICT_COLOUR[CandidateVerdict.ADD])
    (threshold,) = [t for t in fig.data if t.name == "significance threshold"]
    np.testing.assert_allclose(threshold.x, stats.chi2.isf(0.01 / 3, table["dof"]))


def test_the_html_file_is_self_contained_and_the_same_each_time(diagnosis, tmp_path):
    """plotly.js inside (no script fetched from anywhere: the report opens offline) and the same bytes for the
    same figure (the workflow's reruns are compared file by file)."""
    for name in ("a", "b"):
        ia.write_html(ia.diagnosis_figure(diagnosis), tmp_path / f"{name}.html")
    text = (tmp_path / "a.html").read_text()
    assert (tmp_path / "a.html").read_bytes() == (tmp_path / "b.html").read_bytes()
    assert not re.search(r"<script[^>]+src=", text)
    assert _carried_plotly(text) == [pages.plotly_js()] and 'id="figure"' in text


def _carried_plotly(text: str) -> list[str]:
    """The plotly.js bundles a page carries, inflated here with base64 and gzip (not with ``pages.unpack``)."""
    return [gzip.decompress(base64.b64decode(packed)).decode("utf-8")
            for packed in re.findall(r'<script type="application/gzip-base64" id="plotly-js">([^<]*)</script>', text)]


def test_a_packed_text_inflates_to_itself_and_plotly_js_to_under_half():
    """``pack``/``unpack``: every text back as it was (gzip's own decompressor reads the packing: a browser's
    DecompressionStream("gzip") does the same), the same text packed to the same bytes; plotly.js, minified
    JavaScript, packs to under 0.45 of its bytes (gzip takes it to about 0.30, base64 adds a third). How much a
    figure's JSON shrinks depends on its numbers (the main job's: 5.6 -> 1.0 MB; benchmarks/README.md)."""
    text = "ä <br> \u003c 10 µm \n" + json.dumps({"x": list(range(1000))})
    assert pages.unpack(pages.pack(text)) == text and pages.pack(text) == pages.pack(text)
    assert gzip.decompress(base64.b64decode(pages.pack(text))).decode("utf-8") == text
    js = pages.plotly_js()
    assert len(pages.packed_plotly_js()) < 0.45 * len(js) and pages.unpack(pages.packed_plotly_js()) == js


def test_a_page_of_the_earlier_plain_form_still_reads(figures, tmp_path):
    """A page written before the packing (each figure's JSON as it is, in a "application/json" element) reads back
    its figures: the report's page is rebuilt from the figures' own pages, which a run may have made earlier."""
    blocks = "".join(f'<script type="application/json" class="figure-data" data-key="demo/{name}" '
                     f'data-label="demo: {name}">{pages.figure_json(figures[name][0])}</script>\n'
                     for name in ("bode", "summary"))
    (tmp_path / "plain.html").write_text(f"<!DOCTYPE html><html><body>{blocks}</body></html>", encoding="utf-8")
    back = pages.read_gallery(tmp_path / "plain.html")
    assert [key for key, _, _ in back] == ["demo/bode", "demo/summary"]
    assert [_as_data(fig) for _, _, fig in back] == [_stored(figures[n][0]) for n in ("bode", "summary")]


# --- (b) in a real browser -------------------------------------------------------------------------------------

#: injected into a copy of a figure's file: waits for plotly, counts what is drawn, then for each target moves the
#: mouse over the data point (its pixel from the subplot's own axes) and reads the hover label plotly draws, then
#: clicks each legend entry of ``toggles`` (mouse down and up on it) and reads its group's traces' visibility
CHECK = r"""
<script>
(function () {
  var targets = %s, toggles = %s;
  function say(out) {
    var pre = document.createElement('pre');
    pre.id = 'result';
    pre.textContent = JSON.stringify(out);
    document.body.appendChild(pre);
  }
  function pixel(gd, t) {
    var trace = gd._fullData[t.curve], layout = gd._fullLayout, xa, ya, x, y;
    var polar = trace.subplot && layout[trace.subplot] && layout[trace.subplot]._subplot;
    if (polar) {  // a polar subplot draws each point at its calcdata x, y on the subplot's own axes
      xa = polar.xaxis; ya = polar.yaxis;
      x = gd.calcdata[t.curve][t.point].x; y = gd.calcdata[t.curve][t.point].y;
    } else {
      xa = layout['xaxis' + trace.xaxis.slice(1)]; ya = layout['yaxis' + trace.yaxis.slice(1)];
      x = xa.d2c(t.x); y = ya.d2c(t.y);
    }
    var box = gd.getBoundingClientRect();  // whole pixels: a mouse event's position is one
    return [Math.round(box.left + xa._offset + xa.c2p(x)), Math.round(box.top + ya._offset + ya.c2p(y))];
  }
  function labels() {
    return Array.prototype.map.call(document.querySelectorAll('.hoverlayer .hovertext'), function (g) {
      var lines = g.querySelectorAll('tspan.line');
      return lines.length ? Array.prototype.map.call(lines, function (s) { return s.textContent; }).join('\n')
                          : g.textContent;
    });
  }
  function visibility(gd, group) {
    return gd._fullData.filter(function (t) { return t.legendgroup === group; })
                       .map(function (t) { return t.visible; });
  }
  function click(gd, out, k) {
    if (k >= toggles.length) { say(out); return; }
    var t = toggles[k], entry = Array.prototype.find.call(document.querySelectorAll('.legend .traces'),
      function (g) { return g.querySelector('.legendtext').textContent === t.entry; });
    var all = function () { return gd._fullData.map(function (trace) { return trace.visible; }); };
    var seen = {entry: t.entry, found: !!entry, before: visibility(gd, t.group), all_before: all()};
    out.toggles.push(seen);
    if (!entry) { click(gd, out, k + 1); return; }
    var box = entry.querySelector('.legendtoggle').getBoundingClientRect();
    var at = {clientX: box.left + box.width / 2, clientY: box.top + box.height / 2, bubbles: true,
              cancelable: true, view: window, button: 0, buttons: 1};
    var toggle = entry.querySelector('.legendtoggle');
    toggle.dispatchEvent(new MouseEvent('mousedown', at));
    toggle.dispatchEvent(new MouseEvent('mouseup', at));
    setTimeout(function () {
      seen.after = visibility(gd, t.group);
      seen.all_after = all();
      click(gd, out, k + 1);
    }, 800);
  }
  function run(tries) {
    var gd = document.getElementById('figure');
    if (!gd || !gd._fullLayout || !gd.calcdata) {
      if (tries > 0) { setTimeout(function () { run(tries - 1); }, 100); } else { say({error: 'no plot'}); }
      return;
    }
    var out = {svg: document.querySelectorAll('.main-svg').length, traces: gd._fullData.length,
               drawn: document.querySelectorAll('g.trace, g.hm').length,
               paths: document.querySelectorAll('g.trace path').length,
               images: document.querySelectorAll('g.hm image').length, hovers: [], toggles: []};
    var i = 0, last = null;
    function next() {
      if (last) { last.dispatchEvent(new MouseEvent('mouseout', {bubbles: true, relatedTarget: document.body})); }
      if (i >= targets.length) { click(gd, out, 0); return; }
      var t = targets[i++], p;
      try { p = pixel(gd, t); } catch (e) { out.hovers.push({error: String(e), labels: []}); next(); return; }
      var under = document.elementFromPoint(p[0], p[1]);
      last = under;
      if (!under) { out.hovers.push({at: p, under: null, labels: []}); next(); return; }
      under.dispatchEvent(new MouseEvent('mousemove', {clientX: p[0], clientY: p[1], bubbles: true,
                                                       cancelable: true, view: window}));
      setTimeout(function () {
        out.hovers.push({at: p, under: under.getAttribute('class'), labels: labels()});
        next();
      }, 250);
    }
    next();
  }
  window.addEventListener('load', function () { setTimeout(function () { run(100); }, 100); });
})();
</script>
"""
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
         "--window-size=1400,1200", "--virtual-time-budget=10000", "--dump-dom"]
browser = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"no {CHROMIUM} (a headless Chromium renders the "
                             "figures: apt-get install -y chromium; .ci/run installs it where it can)")


def in_browser(figure_html: Path, targets: list[dict], work: Path, toggles: list[dict] = (), key: str = "") -> dict:
    """What the page says (``CHECK``) once Chromium has loaded a copy of ``figure_html`` with the check injected.
    toggles: legend entries to click, {"entry": its text, "group": its legend group}. key: the figure a gallery
    shows (the URL's fragment)."""
    page = work / f"checked_{figure_html.name}"
    text = figure_html.read_text()
    assert text.count("</body>") == 1
    points = [{k: t[k] for k in t if k != "expect"} for t in targets]
    page.write_text(text.replace("</body>", CHECK % (json.dumps(points), json.dumps(list(toggles))) + "</body>"))
    return page_result(page, work, key)


def dumped(page: Path, work: Path, key: str = "") -> subprocess.CompletedProcess:
    """Headless Chromium's run on ``page`` (at the URL's fragment ``key``): its stdout, the page once loaded."""
    return subprocess.run([str(CHROMIUM), *FLAGS, f"--user-data-dir={work / 'chromium-profile'}",
                           page.as_uri() + (f"#{key}" if key else "")],
                          capture_output=True, text=True, timeout=300, check=False)


def page_result(page: Path, work: Path, key: str = "") -> dict:
    """What a check injected into ``page`` wrote into its <pre id="result"> (JSON)."""
    done = dumped(page, work, key)
    found = re.search(r'<pre id="result">(.*?)</pre>', done.stdout, re.DOTALL)
    assert found, f"no result in the page (exit {done.returncode}): {done.stderr[-1500:]}"
    return json.loads(html.unescape(found.group(1)))


def _value(text: str) -> float:
    return float(text.replace("\u2212", "-").replace(",", ""))


def hover_problems(result: dict, targets: list[dict]) -> list[str]:
    """Each target without a hover label that holds its expected text and values (``expect``: (regex with one
    number group, value), or plain text); empty when every hover worked."""
    problems = []
    for target, seen in zip(targets, result["hovers"]):
        text = "\n".join(seen.get("labels", []))
        if not text:
            problems.append(f"{target}: no hover label ({seen})")
            continue
        for expect in target["expect"]:
            if isinstance(expect, str):
                if expect not in text:
                    problems.append(f"{target}: {expect!r} not in the label {text!r}")
                continue
            pattern, value = expect
            found = re.search(pattern, text)
            if not found or not np.isclose(_value(found.group(1)), value, rtol=1e-3, atol=1e-12):
                problems.append(f"{target}: {pattern!r} = {value:.6g} not in the label {text!r}")
    if len(result["hovers"]) != len(targets):
        problems.append(f"{len(result['hovers'])} hovers for {len(targets)} targets")
    return problems


def _index(fig, trace) -> int:
    return next(i for i, t in enumerate(fig.data) if t is trace)


def _figures(comparisons, dense, rotor, ledger_errors, diagnosis) -> dict:
    """Each figure, the points to hover, with what the label must say (values computed here from the data), and
    the legend entries to click (none: the figure's hover only)."""
    out = {}
    fig = ia.runs_figure(comparisons, "demo")
    residual = _traces(fig, 2, 2, "v: x", "scatter")[0]
    k = int(np.argmax(np.abs(residual.y)))
    out["runs"] = (fig, [{"curve": _index(fig, residual), "x": float(residual.x[k]), "y": float(residual.y[k]),
                          "expect": ["v (validation, predicted)", "x residual",
                                     (r"x residual (\S+) um", residual.y[k])]}],
                   [{"entry": "r600_m20: x", "group": "r600_m20: x"}])  # a hidden run's probe shown
    fig = ia.bode_figure(dense, comparisons, "demo")
    c = next(c for c in comparisons if c.run == "r900_m20")
    point = [t for t in _traces(fig, 1, 1) if t.name.split(" ")[0] == c.run][0]
    up = _traces(fig, 1, 1, "20 g model, run-up")[0]
    k = int(np.flatnonzero(np.asarray(up.x) == 1030.0)[0])  # in the jump band: the run-down stands apart
    out["bode"] = (fig, [
        {"curve": _index(fig, point), "x": c.rpm, "y": float(point.y[0]),
         "expect": ["r900_m20", "measured", (r"\|x, 1X\| (\S+) um", abs(c.measured[0, 0]) * 1e6)]},
        {"curve": _index(fig, up), "x": 1030.0, "y": float(up.y[k]),
         "expect": ["20 g model, run-up", (r"(\S+) RPM", 1030.0), (r"\|x, 1X\| (\S+) um", abs(_one_mode(1030.0, 20.0))
                                                                   * 1e6)]}],
        [{"entry": point.name, "group": point.legendgroup}])  # a run's points hidden
    fig = ia.polar_figure(dense, comparisons, "demo")
    c = next(c for c in comparisons if c.run == "r900_m20")  # at the resonance: apart from the curve's points
    (point,) = [t for t in _polar(fig, 1, 1, next(t.name for t in fig.data if t.name.startswith(c.run)))]
    X = c.measured[0, 0]
    out["polar"] = (fig, [{"curve": _index(fig, point), "point": 0,
                           "expect": ["r900_m20", (r"\|x, 1X\| (\S+) um", abs(X) * 1e6),
                                      (r"phase (\S+) deg", np.degrees(np.angle(X)))]}])
    model, values = rotor
    fig = im.campbell_figure(model, values, np.linspace(0.0, 20000.0, 41), run_rpm=[3000.0, 4000.0], n_modes=6)
    frequency = [t for t in fig.data if t.name == "1F: forward whirl, branch 1"][0]
    k = 30  # 15000 RPM: forward and backward well apart
    out["campbell"] = (fig, [{"curve": _index(fig, frequency), "x": float(frequency.x[k]),
                              "y": float(frequency.y[k]),
                              "expect": ["forward whirl, branch 1", (r"(\S+) RPM", 15000.0),
                                         (r"(\S+) Hz", frequency.y[k])]}])
    fig = im.mode_shapes_figure(model, values, 3000.0, n_modes=4)
    shape = [t for t in fig.data if t.name.startswith("mode 2:") and t.mode == "lines"][0]
    nodes = [t for t in fig.data if t.legendgroup == shape.name and t.mode == "markers"][0]
    k = int(np.argmax(np.abs(nodes.y)))
    bearing = [t for t in fig.data if t.name == "bearings" and t.xaxis == shape.xaxis][0]
    out["modes"] = (fig, [
        {"curve": _index(fig, nodes), "x": float(nodes.x[k]), "y": float(nodes.y[k]),
         "expect": ["mode 2", (r"node at z (\S+) m", nodes.x[k]), (r"deflection (\S+)", nodes.y[k])]},
        {"curve": _index(fig, bearing), "x": float(bearing.x[1]), "y": 0.0,
         "expect": ["bearing b (node 13)", (r"z (\S+) m", model.shaft.z[13])]}])
    ledger, errors = ledger_errors
    fig = ia.summary_figure(ledger, errors)
    (heatmap,) = [t for t in fig.data if t.type == "heatmap"]
    i = list(summary.run_order(errors)["run"]).index("v")
    out["summary"] = (fig, [{"curve": _index(fig, heatmap), "x": 0, "y": i,
                             "expect": ["run * v", "variant base", "beyond the noise",
                                        (r"chi\^2/dof (\S+)", errors["base"].set_index("run").at["v", "chi2_dof"])]}])
    fig = ia.diagnosis_figure(diagnosis)
    (bars,) = [t for t in fig.data if t.type == "bar"]
    out["diagnosis"] = (fig, [{"curve": _index(fig, bars), "x": 250.0, "y": "slope_spring",
                               "expect": ["slope_spring", (r"score statistic (\S+)", 500.0)]}])
    return out


@pytest.fixture(scope="module")
def figures(comparisons, dense, rotor, ledger_errors, diagnosis):
    return _figures(comparisons, dense, rotor, ledger_errors, diagnosis)


NAMES = ["runs", "bode", "polar", "campbell", "modes", "summary", "diagnosis"]


@pytest.fixture(scope="module")
def gallery(figures, tmp_path_factory) -> Path:
    """Every figure in one page (the report's), keyed as the workflow keys them: "<variant>/<figure>"."""
    path = tmp_path_factory.mktemp("gallery") / "interactive.html"
    pages.write_gallery([(f"demo/{name}", f"demo: {name}", figures[name][0]) for name in NAMES], path)
    return path


def _as_data(fig) -> dict:
    """A figure as plain data (its JSON parsed): equal for equal figures, whatever the order of their keys."""
    return json.loads(fig.to_json())


def _stored(fig) -> dict:
    """What a page stores of ``fig``: its data with the float arrays in single precision."""
    return _as_data(pio.from_json(pages.single_precision(fig.to_json())))


def test_single_precision_keeps_every_value_to_float32_and_halves_the_arrays():
    """The stored arrays are numpy's float32 rounding of the figure's float64 values (decoded here from the JSON
    with base64 and numpy, not with plotly), in about half the bytes, and storing again changes nothing."""
    values = np.random.default_rng(5).normal(size=4000) * 10.0 ** np.arange(-8, 8).repeat(250)
    fig = go.Figure(go.Scatter(x=values, y=-values, customdata=values, error_y={"array": values}))
    text = fig.to_json()
    stored = pages.single_precision(text)
    trace = json.loads(stored)["data"][0]
    if isinstance(json.loads(text)["data"][0]["x"], list):
        # plotly < 6 (the floor, 5.22) writes arrays as JSON lists of float64's shortest repr: nothing to shorten,
        # and every value must come back as it was
        assert stored == text
        assert np.array_equal(trace["x"], values) and np.array_equal(trace["error_y"]["array"], values)
        return

    def decoded(array: dict) -> np.ndarray:
        assert array["dtype"] == "f4"
        return np.frombuffer(base64.b64decode(array["bdata"]), "<f4").astype(float)

    for got, sign in ((trace["x"], 1), (trace["y"], -1), (trace["customdata"], 1), (trace["error_y"]["array"], 1)):
        assert np.array_equal(sign * decoded(got), values.astype(np.float32).astype(float))
    assert len(stored) < 0.55 * len(text)  # 4 bytes a value against 8, base64 for both
    assert pages.single_precision(stored) == stored
    assert json.loads(pages.single_precision(pio.from_json(stored).to_json())) == json.loads(stored)


def test_a_page_reads_back_its_figures_and_the_gallery_holds_plotly_once(figures, gallery, tmp_path):
    """write_figure/read_figure and write_gallery/read_gallery are exact inverses (the figures' JSON equal); the
    gallery carries plotly.js once, and otherwise only the figures' data and a few kB of page: smaller than two
    pages of one figure each."""
    for name in NAMES:
        ia.write_html(figures[name][0], tmp_path / f"{name}.html")
        assert _as_data(pages.read_figure(tmp_path / f"{name}.html")) == _stored(figures[name][0])
    back = pages.read_gallery(gallery)
    assert [(key, label) for key, label, _ in back] == [(f"demo/{n}", f"demo: {n}") for n in NAMES]
    assert all(_as_data(fig) == _stored(figures[n][0]) for (_, _, fig), n in zip(back, NAMES, strict=True))
    # what a page stores, read and written again, reads back the same
    ia.write_html(pages.read_figure(tmp_path / f"{NAMES[0]}.html"), tmp_path / "again.html")
    assert _as_data(pages.read_figure(tmp_path / "again.html")) == _stored(figures[NAMES[0]][0])
    text = gallery.read_text(encoding="utf-8")
    assert _carried_plotly(text) == [pages.plotly_js()] and pages.read_plotly_js(gallery) == pages.plotly_js()
    data = sum(len(pages.pack(pages.figure_json(figures[n][0]))) for n in NAMES)
    assert len(text) < len(pages.packed_plotly_js()) + data + 10_000, (len(text), data)
    two = sum(len((tmp_path / f"{n}.html").read_text(encoding="utf-8")) for n in NAMES[:2])
    assert len(text) < two


@browser
@pytest.mark.parametrize("in_gallery", [False, True], ids=["own page", "gallery"])
@pytest.mark.parametrize("name", NAMES)
def test_the_figure_renders_and_its_hover_gives_the_points_value_in_a_browser(figures, gallery, name, in_gallery,
                                                                              tmp_path):
    """The check, on the figure's own page and on the gallery showing it (chosen by the URL's fragment)."""
    fig, targets, *toggles = figures[name]
    toggles = toggles[0] if toggles else []
    if in_gallery:
        result = in_browser(gallery, targets, tmp_path, toggles, key=f"demo/{name}")
    else:
        ia.write_html(fig, tmp_path / f"{name}.html")
        result = in_browser(tmp_path / f"{name}.html", targets, tmp_path, toggles)
    assert "error" not in result, result
    visible = sum(1 for t in fig.data if t.visible in (None, True))
    assert result["svg"] >= 1 and result["traces"] == len(fig.data)
    assert result["drawn"] >= visible and result["paths"] + result["images"] > 0, result
    assert all("drag" in (seen.get("under") or "") for seen in result["hovers"]), result["hovers"]
    assert not hover_problems(result, targets), hover_problems(result, targets)
    # a click on a legend entry shows a hidden group, or hides a shown one: every trace of the group
    flip = {True: "legendonly", "legendonly": True}
    for toggle, seen in zip(toggles, result["toggles"], strict=True):
        assert seen["found"] and len(seen["before"]) > 1, seen
        assert seen["after"] == [flip[v] for v in seen["before"]], seen
        changed = sum(a != b for a, b in zip(seen["all_before"], seen["all_after"], strict=True))
        assert changed == len(seen["before"]), f"{changed} traces changed, the group has {len(seen['before'])}"


@browser
@pytest.mark.parametrize("switch_off", ["hoverinfo", "hovermode"])
def test_the_browser_check_fails_where_hover_is_switched_off(figures, switch_off, tmp_path):
    """The same check on the Bode figure with hover switched off, every trace's (hoverinfo "skip"; a hovertemplate
    would still win over it in plotly.js, so it goes too) or the layout's (hovermode False): the figure renders,
    but no label comes, and the check says so for every point."""
    fig, targets, _ = figures["bode"]
    broken = go.Figure(fig)
    if switch_off == "hoverinfo":
        broken.update_traces(hoverinfo="skip", hovertemplate=None)
    else:
        broken.update_layout(hovermode=False)
    ia.write_html(broken, tmp_path / "broken.html")
    result = in_browser(tmp_path / "broken.html", targets, tmp_path)
    assert result["svg"] >= 1 and result["paths"] > 0
    problems = hover_problems(result, targets)
    assert len(problems) == len(targets) and all("no hover label" in p for p in problems), problems


#: injected into a copy of the gallery: chooses two figures from the menu one right after the other (each inflated as
#: it is chosen, the first possibly after the second), either at once, as the page is parsed (plotly.js not inflated
#: yet), or once the first figure is drawn; then says what is drawn
MENU = r"""
<script>
(function () {
  var choices = %s, early = %s, first = null;
  function say(out) {
    var pre = document.createElement('pre');
    pre.id = 'result';
    pre.textContent = JSON.stringify(out);
    document.body.appendChild(pre);
  }
  function drawn(gd) { return gd._fullLayout ? gd._fullLayout.title.text : null; }
  function choose_all() {
    var choose = document.getElementById('choose');
    choices.forEach(function (key) { choose.value = key; choose.dispatchEvent(new Event('change')); });
  }
  function report() {
    var gd = document.getElementById('figure');
    say({first: first, last: drawn(gd), traces: gd._fullData ? gd._fullData.length : 0, hash: location.hash,
         title: document.title, menu: document.getElementById('choose').value});
  }
  function run(tries) {
    var gd = document.getElementById('figure');
    if (!drawn(gd)) {
      if (tries > 0) { setTimeout(function () { run(tries - 1); }, 100); } else { say({error: 'no plot'}); }
      return;
    }
    first = drawn(gd);
    if (!early) { choose_all(); }
    setTimeout(report, 3000);
  }
  if (early) { choose_all(); }
  window.addEventListener('load', function () { setTimeout(function () { run(100); }, 100); });
})();
</script>
"""


@browser
@pytest.mark.parametrize("early", [False, True], ids=["after the first figure", "before plotly.js is inflated"])
def test_the_gallerys_menu_draws_the_figure_chosen_last(figures, gallery, early, tmp_path):
    """The gallery opens on its first figure; two figures chosen from the menu one right after the other (each
    inflated when chosen), once the first is drawn or before plotly.js is even inflated: the one chosen last is
    drawn, with its own traces, title and address fragment."""
    page = tmp_path / "menu.html"
    page.write_text(gallery.read_text().replace("</body>", MENU % (json.dumps(["demo/summary", "demo/diagnosis"]),
                                                                   json.dumps(early)) + "</body>"))
    result = page_result(page, tmp_path)
    runs, diagnosis = figures["runs"][0], figures["diagnosis"][0]
    # drawn first: the runs figure (the gallery's first), or already the last choice when it came before any draw
    assert result["first"] == (diagnosis if early else runs).layout.title.text, result
    assert result["last"] == diagnosis.layout.title.text and result["traces"] == len(diagnosis.data), result
    assert result["hash"] == "#demo%2Fdiagnosis" and result["menu"] == "demo/diagnosis"
    assert result["title"] == "demo: diagnosis"


@browser
def test_a_browser_without_decompression_streams_is_told_so(figures, tmp_path):
    """Where the browser lacks DecompressionStream (before Chrome 80, Firefox 113, Safari 16.4), the page says what
    it needs in place of the figure, and draws nothing."""
    ia.write_html(figures["diagnosis"][0], tmp_path / "page.html")
    text = (tmp_path / "page.html").read_text()
    (tmp_path / "old.html").write_text(text.replace("<body>", "<body>\n<script>delete window.DecompressionStream;"
                                                    "</script>", 1))
    done = dumped(tmp_path / "old.html", tmp_path)
    found = re.search(r'<div id="figure"[^>]*>(.*?)</div>', done.stdout, re.DOTALL)
    assert found, done.stdout[-1500:]
    assert "needs DecompressionStream" in found.group(1) and "main-svg" not in done.stdout
