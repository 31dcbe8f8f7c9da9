"""Every figure function writes a non-empty PNG for small inputs."""

import numpy as np
import pytest

from calnet.errors import SpecError
from calnet.report import figures as F
from calnet.report.network_diagram import topological_depth

PNG = b"\x89PNG\r\n\x1a\n"


def _is_png(path):
    data = path.read_bytes()
    return len(data) > 1000 and data.startswith(PNG)


def _param(name, lo, hi, **extra):
    xs = np.linspace(lo, hi, 20)
    samples = np.random.default_rng(0).uniform(lo, hi, 200)
    return dict(name=name, unit="W", lower=lo, upper=hi, prior_pdf_x=xs,
                prior_pdf_y=np.full(20, 1 / (hi - lo)), posterior_samples=samples, **extra)


def test_data_grid(tmp_path):
    P, v = np.array([70.0, 150.0, 250.0]), np.array([0.1, 1.0, 2.0])
    out = F.data_grid(P, v, {"width": (P, v, [False, True, False]), "pdas": (P[:2], v[:2])},
                      tmp_path / "sub" / "grid.png")
    assert _is_png(out)
    assert _is_png(F.data_grid(None, None, {"width": (P, v)}, tmp_path / "g2.png"))


def test_prior_posterior_and_grid(tmp_path):
    p = _param("K_S", 60.0, 100.0, mode=70.0, reference=68.0)
    assert _is_png(F.prior_posterior(**p, path=tmp_path / "pp.png"))
    params = [p, _param("sigma", 2e-7, 1e-6, mode=4e-7, reference=1.1e-7), _param("M", 5, 15)]
    assert _is_png(F.prior_posterior_grid(params, tmp_path / "ppg.png", ncols=2, title="M1"))


def test_prior_posterior_degenerate_samples(tmp_path):
    p = _param("K", 0.0, 1.0)
    p["posterior_samples"] = np.full(10, 0.5)  # no spread: histogram only, no KDE
    assert _is_png(F.prior_posterior(**p, path=tmp_path / "pp.png"))


def test_predictive_vs_observed(tmp_path):
    y = np.array([0.3, 0.35, 0.4, 0.33])
    out = F.predictive_vs_observed(y, y + 0.01, y - 0.02, y + 0.03, [False, False, True, True],
                                   tmp_path / "pvo.png", "PDAS", "um")
    assert _is_png(out)


def test_a_log_output_over_decades_gets_log_axes(tmp_path, monkeypatch):
    """A log-modelled output spanning three decades is drawn on log axes; over less than
    a decade, or modelled linearly, it keeps linear ones."""
    saved = []
    save = F._save
    monkeypatch.setattr(F, "_save", lambda fig, path: saved.append(fig) or save(fig, path))
    wide, narrow = np.array([0.01, 0.1, 1.0, 10.0]), np.array([0.3, 0.35, 0.4, 0.33])
    for y, log in ((wide, True), (wide, False), (narrow, True)):
        assert _is_png(F.predictive_vs_observed(y, 1.1 * y, 0.8 * y, 1.3 * y, [False] * 4,
                                                tmp_path / "p.png", "d", "um", log=log))
    scales = [(f.axes[0].get_xscale(), f.axes[0].get_yscale()) for f in saved]
    assert scales == [("log", "log"), ("linear", "linear"), ("linear", "linear")]


def test_maps(tmp_path):
    Pg, vg = np.linspace(65, 260, 6), np.linspace(0.04, 2.4, 5)
    z = Pg[None, :] / 100 + vg[:, None]
    pts = np.array([[100.0, 0.5], [200.0, 1.5]])
    assert _is_png(F.predictive_map(Pg, vg, z, tmp_path / "m.png", "W", "um", points=pts))
    PP, VV = np.meshgrid(Pg, vg)
    assert _is_png(F.predictive_map(PP, VV, z, tmp_path / "m2.png", "W", "um",
                                    points={"width": pts}))
    prob = np.clip(z / z.max(), 0, 1)
    assert _is_png(F.process_map(Pg, vg, prob, tmp_path / "p.png", "W > 80 um", points=pts))
    with pytest.raises(ValueError, match="grid shapes"):
        F.predictive_map(Pg, vg, z.T, tmp_path / "bad.png", "W", "um")


def test_sobol_bars(tmp_path):
    out = F.sobol_bars(["P", "v"], [0.1, 0.8], [0.02, 0.05], [0.15, 0.85], [0.03, 0.04],
                       tmp_path / "s.png", "PDAS")
    assert _is_png(out)


def test_network_diagram(tmp_path):
    models = [dict(name="melt_pool", inputs=["P", "v", "K_S"], outputs=["W", "G", "R"],
                   measurable=["W"]),
              dict(name="solidification", inputs=["G", "R"], outputs=["lambda"],
                   measurable=True),
              dict(name="extra", inputs=["lambda"], outputs=["y"], measurable=[])]
    links = [("melt_pool", "solidification", "G"), ("melt_pool", "solidification", "R"),
             ("solidification", "extra", "lambda")]
    assert _is_png(F.network_diagram(models, links, tmp_path / "net.png", title="net"))
    assert topological_depth(["a", "b", "c"], [("a", "c", ""), ("b", "c", "")]) == {
        "a": 0, "b": 0, "c": 1}


def test_network_cycle_and_unknown_model_rejected():
    with pytest.raises(SpecError, match="cycle"):
        topological_depth(["a", "b"], [("a", "b", ""), ("b", "a", "")])
    with pytest.raises(SpecError, match="unknown model 'z'"):
        topological_depth(["a"], [("a", "z", "")])


@pytest.fixture
def drawn(monkeypatch):
    """The matplotlib figures the figure functions save, drawn (text extents known)."""
    from matplotlib.figure import Figure

    figs, save = [], Figure.savefig

    def keep(self, *args, **kwargs):
        figs.append(self)
        return save(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return figs


def _renderer(fig):
    """Draw ``fig`` (layout included) on an Agg canvas and return its renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _kde_line(fig):
    (line,) = [ln for ax in fig.axes for ln in ax.get_lines()
               if ln.get_label() == "posterior KDE"]
    return line.get_xdata(), line.get_ydata()


@pytest.mark.parametrize("lo, hi", [(0.0, 1.0), (60.0, 100.0), (2e-7, 1e-6)])
def test_reflected_kde_matches_a_uniform_density_up_to_the_bounds(lo, hi):
    """For uniform draws the reflected KDE is flat at 1 / (hi - lo) up to both bounds and
    integrates to 1 over them; a plain KDE drops to about half at a bound. Tolerance: the
    KDE's Monte Carlo sd at a bound, sqrt(2 f R(K) / (n h)) with R(K) = 1 / (2 sqrt(pi)),
    is about 3.6 % of f for n = 20000 (h = 0.04 of the range); 12 % is over 3 sd."""
    from scipy.stats import gaussian_kde

    n = 20_000
    draws = np.random.default_rng(1).uniform(lo, hi, n)
    exact = 1.0 / (hi - lo)
    xs = np.linspace(lo, hi, 401)
    f = F.reflected_kde(draws, lo, hi, xs)
    assert np.max(np.abs(f / exact - 1.0)) < 0.12
    assert abs(np.trapezoid(f, xs) - 1.0) < 2e-3
    plain = gaussian_kde(draws)([lo, hi]) / exact  # what the reflection corrects
    assert np.all((plain > 0.4) & (plain < 0.6))
    assert np.all(F.reflected_kde(draws, lo, hi, [lo - 0.1 * (hi - lo), hi * 1.1]) == 0.0)


def test_reflected_kde_follows_a_truncated_normal():
    """Draws of N(0.1, 0.3) truncated to [0, 1] (high density at the lower bound): the
    reflected KDE follows the exact density within 10 % of its peak everywhere (the
    reflection's remaining bias is in the slope at the bound, O(h) of the peak)."""
    from scipy.stats import truncnorm

    dist = truncnorm((0.0 - 0.1) / 0.3, (1.0 - 0.1) / 0.3, loc=0.1, scale=0.3)
    draws = dist.rvs(20_000, random_state=np.random.default_rng(2))
    xs = np.linspace(0.0, 1.0, 201)
    exact = dist.pdf(xs)
    assert np.max(np.abs(F.reflected_kde(draws, 0.0, 1.0, xs) - exact)) < 0.10 * exact.max()


def test_posterior_panel_density_does_not_drop_at_the_bounds(tmp_path, drawn):
    """The KDE drawn in a prior-vs-posterior panel stays at the density at the bounds."""
    p = _param("K", 60.0, 100.0)
    p["posterior_samples"] = np.random.default_rng(3).uniform(60.0, 100.0, 20_000)
    F.prior_posterior(**p, path=tmp_path / "pp.png")
    xs, ys = _kde_line(drawn[-1])
    assert xs[0] == 60.0 and xs[-1] == 100.0
    assert np.all(np.abs(ys[[0, -1]] * 40.0 - 1.0) < 0.12)


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_data_grid_legend_is_off_the_axes(tmp_path, drawn):
    """The legend of the experimental settings sits beside the axes, on no data point."""
    rng = np.random.default_rng(4)
    P, v = rng.uniform(70, 250, 40), rng.uniform(0.1, 2.4, 40)
    F.data_grid(None, None, {"width": (P, v, rng.random(40) < 0.25), "pdas": (P[:8], v[:8])},
                tmp_path / "grid.png")
    fig = drawn[-1]
    (ax,) = fig.axes
    renderer = _renderer(fig)
    legend = ax.get_legend().get_window_extent(renderer)
    assert not _overlap(legend, ax.get_window_extent(renderer))
    assert legend.x1 <= fig.bbox.x1 + 1  # and inside the figure


def _three_models():
    models = [dict(name="thermal", inputs=["P", "v"], outputs=["W", "G"], measurable=["W"]),
              dict(name="micro", inputs=["G", "S"], outputs=["lam"], measurable=["lam"]),
              dict(name="hardness", inputs=["lam"], outputs=["H"], measurable=True)]
    links = [("thermal", "micro", "G->G"), ("thermal", "micro", "v->S"),
             ("micro", "hardness", "lam->lam")]
    return models, links


def test_three_model_network_diagram_is_readable(tmp_path, drawn):
    """Every text is at least 9 pt at its displayed size (the PNG fits the report's
    1000 px column, so it is not scaled down), lies inside its model's box, and no two
    texts overlap; arrow labels overlap no box."""
    from matplotlib.patches import FancyBboxPatch

    models, links = _three_models()
    path = F.network_diagram(models, links, tmp_path / "net.png")
    fig = drawn[-1]
    width_px = fig.get_figwidth() * 110
    assert width_px <= 1000, "wider than the report's column: the browser shrinks it"
    renderer = _renderer(fig)
    ax = fig.axes[0]
    boxes = {p.get_gid(): p.get_window_extent(renderer) for p in ax.patches
             if isinstance(p, FancyBboxPatch)}
    assert set(boxes) == {f"box {m['name']}" for m in models}
    texts = [t for t in ax.texts if t.get_text()]
    for t in texts:
        assert t.get_fontsize() >= 9, t.get_text()
    extents = [(t, t.get_window_extent(renderer)) for t in texts]
    for t, ext in extents:
        if t.get_gid() in boxes:
            box = boxes[t.get_gid()]
            assert box.x0 < ext.x0 and ext.x1 < box.x1 and box.y0 < ext.y0 and ext.y1 < box.y1, (
                t.get_text())
        else:
            frame = t.get_bbox_patch().get_window_extent(renderer)
            assert not any(_overlap(frame, b) for b in boxes.values()), t.get_text()
    for i, (a, ea) in enumerate(extents):
        for b, eb in extents[i + 1:]:
            assert not _overlap(ea, eb), (a.get_text(), b.get_text())
    assert _is_png(path)
