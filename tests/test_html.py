"""Interactive pages (``grasp-jax show FILE --html PAGE``, :mod:`grasp_jax.interactive`), checked in
a real browser: headless Chromium (Debian's package at ``/usr/bin/chromium``, driven by Playwright
for Python) with the network off and a fresh profile.

The browser tests skip, saying why, where no Chromium (or no Playwright) is installed;
``GRASP_JAX_REQUIRE_CHROMIUM=1`` (set by ``.ci/run``) turns that skip into a failure, so CI never
skips them. ``GRASP_JAX_CHROMIUM=PATH`` points at another Chromium binary.

Result files here are written directly (grasps sampled on the object, made-up scores and extra
columns), so that nothing compiles: the page must not depend on what produced the file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from grasp_jax import interactive, objects, storage
from grasp_jax.sampling import sample_grasps

CHROMIUM = Path(os.environ.get("GRASP_JAX_CHROMIUM", "/usr/bin/chromium"))
#: Flags of every browser run: no network, no background services, no GPU (software WebGL).
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
]
MAX_PAGE_BYTES = 10 * 1024 * 1024
EXTRA = ("p_force_closure", "crit_mu", "jaw_pose")


def write_result(path: Path, obj, num: int, fingers: int, *, seed=0, optimizer=False, extra=True) -> Path:
    """A result file as ``grasp-jax sample`` (or ``optimize``) writes it, with made-up scores and
    columns a later version may add (a probability of force-closure, a critical friction, jaw
    poses)."""
    rng = np.random.default_rng(seed)
    p, n = sample_grasps(obj, num, fingers, seed=seed)
    q = rng.uniform(0, 1, num)
    fc = rng.uniform(size=num) < 0.3
    arrays = {"points": p, "normals": n, "force_closure": fc, "quality": np.where(fc, q, 0.0),
              "converged": np.ones(num, bool)}
    if extra:
        arrays.update(p_force_closure=rng.uniform(size=num), crit_mu=rng.uniform(0.1, 1, num),
                      jaw_pose=rng.normal(size=(num, 7)))
    if optimizer:
        p0, _ = sample_grasps(obj, num, fingers, seed=seed + 1)
        arrays.update(initial_points=p0, objective=q, reason=rng.integers(0, 3, num).astype(np.int8),
                      history=np.cumsum(rng.uniform(size=(num, 12)), axis=1) / 12,
                      quality_history=np.cumsum(rng.uniform(size=(num, 12)), axis=1) / 12,
                      path=p0[:, None] + np.linspace(0, 1, 5)[None, :, None, None] * (p - p0)[:, None])
    meta = storage.metadata(command="optimize" if optimizer else "sample", object=str(obj.name) if
                            str(obj.name) in objects.BUILTIN_NAMES else None, mu=0.364, edges=8,
                            fingers=fingers, num=num)
    np.savez(path, metadata=np.array(json.dumps(meta)), **arrays)
    return path


@pytest.fixture(scope="module")
def glass():
    return objects.load("glass")


@pytest.fixture(scope="module")
def pages(tmp_path_factory, glass, mesh_dir):
    """Pages to open: 100,000 grasps of the YCB mug, an optimizer result, a planar polygon."""
    d = tmp_path_factory.mktemp("pages")
    mug = objects.load(mesh_dir / "ycb_025_mug.obj")
    t = time.perf_counter()
    big = write_result(d / "mug.npz", mug, 100_000, 4)
    written = time.perf_counter() - t
    t = time.perf_counter()
    out = {"mug": interactive.result_page(big, d / "mug.html", top=10, obj=mug)}
    built = time.perf_counter() - t
    print(f"100,000-grasp file written in {written:.1f} s, page built in {built:.2f} s, "
          f"{out['mug'].stat().st_size / 1e6:.2f} MB")
    out["opt"] = interactive.result_page(write_result(d / "opt.npz", glass, 64, 4, optimizer=True),
                                         d / "opt.html", top=5)
    star = objects.load("star")
    out["star"] = interactive.result_page(write_result(d / "star.npz", star, 500, 3), d / "star.html", top=3)
    return out


# ------------------------------------------------------------------------------------------------
# Without a browser


def test_select_grasps_ranks_and_reads_every_column(tmp_path, glass):
    f = write_result(tmp_path / "r.npz", glass, 3000, 4, optimizer=True)
    shown, meta = interactive.select_grasps(f, 7, chunk=1000)  # the ranking crosses chunks
    arrays, _ = storage.read_results(f)
    key = np.lexsort((np.arange(3000), -arrays["quality"], ~arrays["force_closure"]))[:7]
    np.testing.assert_array_equal(shown.index, key)
    np.testing.assert_array_equal(shown.points, arrays["points"][key])
    for name in EXTRA + ("initial_points", "quality_history", "reason", "converged"):
        np.testing.assert_array_equal(shown.columns[name], arrays[name][key])
    assert shown.num == 3000 and shown.num_force_closure == int(arrays["force_closure"].sum())
    counts, edges = shown.histogram
    assert counts.sum() == shown.num_force_closure and edges[0] == 0
    assert meta["mu"] == 0.364


def test_page_is_self_contained_and_lists_the_columns(pages):
    text = pages["opt"].read_text(encoding="utf-8")
    assert "<script src" not in text and "<link" not in text  # plotly's script is inline: nothing to fetch
    for word in EXTRA + ("force-closure reached", "initial_points", "central axis", "contact paths",
                         "Q against step", "5 positions from the start to the last step"):
        assert word in text, word


def test_page_of_100000_grasps_on_a_ycb_mesh_is_small(pages):
    size = pages["mug"].stat().st_size
    assert size <= MAX_PAGE_BYTES, f"{size / 1e6:.1f} MB"
    text = pages["mug"].read_text(encoding="utf-8")
    assert "best 10 of 100,000 grasps" in text


def test_large_meshes_are_decimated_with_a_note(glass):
    v, f, note = interactive.display_mesh(glass.mesh.vertices, glass.mesh.faces, 2000)
    assert 0 < len(f) <= 2000 and f.max() < len(v)
    assert "decimated" in note and "9,486" in note
    same = interactive.display_mesh(glass.mesh.vertices, glass.mesh.faces, 20_000)
    assert same[2] is None and len(same[1]) == 9486


def test_central_axis_passes_through_c1_inside_its_negative_cone():
    # four contacts at a regular tetrahedron's vertices on the unit sphere: force-closure
    p = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / np.sqrt(3)
    point, direction = interactive.balancing_axis(p, p, mu=0.5, num_edges=8)
    assert np.linalg.norm(np.cross(point - p[0], direction)) < 1e-7  # c_1 is on the axis
    angle = np.arccos(np.clip(direction @ p[0], -1, 1))  # the force of contacts 2..n points outward
    assert angle <= np.arctan(0.5) + 1e-6
    assert interactive.balancing_axis(p[:2], p[:2], mu=0.1) is None  # two hard contacts: no equilibrium


def test_grasp_page_from_arrays(tmp_path, glass):
    p, n = sample_grasps(glass, 3, 4, seed=1)
    page = interactive.grasp_page(glass.mesh, p, n, tmp_path / "g.html", mu=0.364,
                                  columns={"quality": [0.3, 0.2, 0.1], "label": ["a", "b", "c"]})
    text = page.read_text(encoding="utf-8")
    assert "label = a" in text and page.stat().st_size < 6e6
    with pytest.raises(ValueError, match="column 'quality' has 2 rows"):
        interactive.grasp_page(glass.mesh, p, n, tmp_path / "h.html", mu=0.364, columns={"quality": [1, 2]})
    with pytest.raises(ValueError, match="must end in .html"):
        interactive.grasp_page(glass.mesh, p, n, tmp_path / "h.png", mu=0.364)


def test_show_html_on_the_command_line(tmp_path, glass, xla_cache):
    f = write_result(tmp_path / "g.npz", glass, 500, 4)
    env = dict(os.environ, GRASP_JAX_CACHE=xla_cache, PYTHONWARNINGS="ignore::DeprecationWarning")
    env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-m", "grasp_jax", "show", "g.npz", "--top", "3", "--html", "g.html"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "page   g.html" in out.stdout and (tmp_path / "g.html").stat().st_size > 1e6
    assert not (tmp_path / "g.png").exists()  # --html alone draws no PNG
    bad = subprocess.run([sys.executable, "-m", "grasp_jax", "show", "g.npz", "--html", "g.txt"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "must end in .html" in bad.stderr


# ------------------------------------------------------------------------------------------------
# In headless Chromium


def _browser_or_skip():
    why = None
    if not CHROMIUM.exists():
        why = (f"no Chromium at {CHROMIUM}: install Debian's package (apt-get install -y chromium) or set "
               "GRASP_JAX_CHROMIUM; .ci/run installs it")
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            why = "Playwright for Python is not installed (pip install -e '.[test]')"
    if why is not None:
        if os.environ.get("GRASP_JAX_REQUIRE_CHROMIUM", "") not in ("", "0"):
            pytest.fail(f"{why}; GRASP_JAX_REQUIRE_CHROMIUM is set, so the browser tests must run")
        pytest.skip(why)


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    _browser_or_skip()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")), executable_path=str(CHROMIUM), headless=True,
            args=CHROMIUM_FLAGS, viewport={"width": 1400, "height": 860}, offline=True)
        try:
            yield context
        finally:
            context.close()


def _open(context, page_path: Path):
    """Open a page; returns ``(page, problems)``: script errors, console errors and every request
    that left the file (all aborted)."""
    problems: list[str] = []
    page = context.new_page()
    page.on("pageerror", lambda e: problems.append(f"script error: {e}"))
    page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)

    def route(r):
        url = r.request.url
        if url.startswith(("file:", "data:", "blob:", "about:")):
            return r.continue_()
        problems.append(f"network request: {url}")
        return r.abort()

    page.route("**/*", route)
    page.goto(page_path.resolve().as_uri())
    page.wait_for_function("() => { const gd = document.querySelector('.js-plotly-plot');"
                           " return gd && gd._fullLayout && gd._fullData && gd._fullData.length > 0; }",
                           timeout=60_000)
    page.wait_for_timeout(700)  # WebGL's first frame
    return page, problems


def _pixels(png: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


def _object_shown(page, what: str) -> None:
    """The screenshot of the main plot shows the object: many pixels that are not background, and
    many that change when the object's trace is hidden."""
    box = page.evaluate("""() => { const gd = document.querySelector('.js-plotly-plot');
        const d = gd._fullLayout.scene ? gd._fullLayout.scene.domain : gd._fullLayout.xaxis.domain
                  && {x: gd._fullLayout.xaxis.domain, y: gd._fullLayout.yaxis.domain};
        const s = gd._fullLayout._size;
        return {x: s.l + d.x[0] * s.w, y: s.t + (1 - d.y[1]) * s.h, width: (d.x[1] - d.x[0]) * s.w,
                height: (d.y[1] - d.y[0]) * s.h}; }""")
    before = _pixels(page.screenshot(clip=box))
    drawn = float((np.abs(before - 255).max(-1) > 24).mean())
    page.evaluate("() => Plotly.restyle(document.querySelector('.js-plotly-plot'), {visible: false}, [0])")
    page.wait_for_timeout(400)
    after = _pixels(page.screenshot(clip=box))
    changed = float((np.abs(before - after).max(-1) > 24).mean())
    page.evaluate("() => Plotly.restyle(document.querySelector('.js-plotly-plot'), {visible: true}, [0])")
    assert drawn > 0.05 and changed > 0.03, f"{what}: {drawn:.1%} of the plot drawn, {changed:.1%} is the object"


def test_pages_open_offline_without_errors_and_show_the_object(browser, pages):
    for name in ("mug", "opt", "star"):
        t = time.perf_counter()
        page, problems = _open(browser, pages[name])
        assert page.evaluate("() => !!window.WebGLRenderingContext")
        _object_shown(page, name)
        # every entry of the grasp menu draws without an error, and draws fewer traces than "all"
        counts = page.evaluate("""async () => { const gd = document.querySelector('.js-plotly-plot');
            const out = [];
            for (const b of gd.layout.updatemenus[0].buttons) {
                await Plotly.restyle(gd, b.args[0]);
                out.push(gd._fullData.filter(t => t.visible === true).length); }
            return out; }""")
        assert len(counts) >= 4 and all(c < counts[0] for c in counts[1:]), counts
        hover = page.evaluate("""() => document.querySelector('.js-plotly-plot').data
            .filter(t => t.hovertext).map(t => String(t.hovertext)).join(' ')""")
        for word in ("grasp #", "Q = ", "crit_mu", "p_force_closure", "jaw_pose"):
            assert word in hover, (name, word)
        page.close()
        assert not problems, (name, problems)
        print(f"{name}: opened and checked in {time.perf_counter() - t:.1f} s")
