"""Shared fixtures of the grasp_jax test suite.

Importing grasp_jax changes no JAX configuration (checked here, on every run, and in a fresh
process by ``test_dtypes.py``). The suite itself then turns on JAX's 64-bit mode, as lineax's does,
so that its comparisons with the float64 references (HiGHS, qhull, finite differences) run in
float64 under ``jit`` and ``grad`` too; ``test_dtypes.py`` checks float32 programs in
subprocesses without it.

Compiling XLA programs is most of the suite's time. ``GRASP_JAX_CACHE`` chooses what is kept:

* unset (the default): the library's own cache (``grasp_jax._cache``, the chunk programs) in a
  folder of this run only, ``xla-cache`` in pytest's base temporary folder, shared by the
  pytest-xdist workers and every process a test starts (the command line, the device layouts,
  the float32 checks) and removed when the run ends: a chunk program is compiled once per run, not
  once per worker and process. JAX's own persistent cache stays off: the programs the tests jit
  themselves are compiled where they are used (a worker aborted three times inside XLA's
  serialization of such small programs for JAX's cache, which under ``--dist loadfile`` also
  hung the run: pytest-xdist issue 784, hence ``--max-worker-restart 0`` in ``pyproject.toml``);
* a folder (``GRASP_JAX_CACHE=.test-cache/xla``; ``.test-cache/`` is git-ignored), for a
  developer who runs the suite again and again: kept between runs, and the test processes switch
  on JAX's own persistent cache there too (the library then only reads its own cache, which
  writes nothing beside JAX's); the processes the tests start inherit ``GRASP_JAX_CACHE`` but not
  JAX's cache (``JAX_COMPILATION_CACHE_DIR`` is removed from the environment): they run as a
  user's processes do;
* ``off``: no cache at all in the test processes (the processes a test starts share one folder
  per worker).

The user's ``~/.cache`` is never read or written.
"""

from __future__ import annotations

import gc
import os
import shutil
import signal
from pathlib import Path
from types import SimpleNamespace

#: The suite's compilation cache (see the docstring), before JAX is imported. ``SESSION`` in the
#: environment marks the default: ``"new"`` until this run's folder is made (``_session_cache``),
#: then that folder, for the workers and the processes the tests start.
SESSION = "GRASP_JAX_SUITE_CACHE"
if "GRASP_JAX_CACHE" not in os.environ:
    os.environ["GRASP_JAX_CACHE"] = "off"  # until the session's folder is made
    os.environ[SESSION] = "new"
SESSION_CACHE = os.environ.get(SESSION)
#: The developer's folder (the library's cache and JAX's), or ``None`` (the values of
#: ``grasp_jax._cache.OFF``, which cannot be imported before JAX, and the session's default).
SUITE_CACHE = None if SESSION_CACHE else os.environ["GRASP_JAX_CACHE"]
if SUITE_CACHE is not None and SUITE_CACHE.strip().lower() in ("", "0", "off", "no", "none", "false"):
    SUITE_CACHE = None
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)  # see the docstring
# The programs the tests jit themselves compiled with LLVM's optimization level 1, as the library's
# chunk programs are (``_batch.COMPILER_OPTIONS``): tests/test_objectives.py took 111 s of CPU
# instead of 123 with an empty cache (level 0: 120, its programs run slower). XLA reads XLA_FLAGS
# once, when JAX makes its backend (below); the caller's value is then put back, so that the
# processes the tests start run as a user's do and the library's cache keys (which name XLA_FLAGS)
# are theirs: a chunk program compiled here is loaded there, and the other way round.
_CALLER_XLA_FLAGS = os.environ.get("XLA_FLAGS")
if "xla_backend_optimization_level" not in (_CALLER_XLA_FLAGS or ""):
    os.environ["XLA_FLAGS"] = ((_CALLER_XLA_FLAGS or "") + " --xla_backend_optimization_level=1").strip()

import hypothesis
import jax
import numpy as np
import pytest

_CONFIG_BEFORE = dict(jax.config.values)
import grasp_jax  # noqa: F401

#: Configuration entries that importing grasp_jax changed (must be none).
IMPORT_CHANGED_CONFIG = {
    key: (_CONFIG_BEFORE.get(key), value)
    for key, value in jax.config.values.items()
    if _CONFIG_BEFORE.get(key, object()) != value
}
assert not IMPORT_CHANGED_CONFIG, f"importing grasp_jax changed JAX's configuration: {IMPORT_CHANGED_CONFIG}"

jax.config.update("jax_enable_x64", True)  # the suite's float64 references; see the docstring
jax.devices()  # the backend, with the XLA_FLAGS above
if _CALLER_XLA_FLAGS is None:
    os.environ.pop("XLA_FLAGS", None)
else:
    os.environ["XLA_FLAGS"] = _CALLER_XLA_FLAGS
if SUITE_CACHE is not None:  # this process only; see the docstring
    jax.config.update("jax_compilation_cache_dir", SUITE_CACHE)
    # Small programs too: the op-by-op ones of un-jitted grads and the surfaces' walks add up to
    # about half of what a run with a filled cache still compiles.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)

from grasp_jax import _cache

assert (_cache.directory() is None) == (SUITE_CACHE is None and SESSION_CACHE in (None, "new"))

#: ``<repo root>/../shared/data``: the real meshes and polygons shared by the project.
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

hypothesis.settings.register_profile(
    "grasp_jax",
    deadline=None,
    max_examples=25,
    derandomize=True,
    suppress_health_check=[hypothesis.HealthCheck.too_slow],
)
# Longer runs: HYPOTHESIS_PROFILE=grasp_jax_long (same examples every run, more of them) or
# grasp_jax_explore (fresh random examples).
hypothesis.settings.register_profile(
    "grasp_jax_long", parent=hypothesis.settings.get_profile("grasp_jax"), max_examples=200
)
hypothesis.settings.register_profile(
    "grasp_jax_explore", parent=hypothesis.settings.get_profile("grasp_jax"), max_examples=200,
    derandomize=False,
)
hypothesis.settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "grasp_jax"))


#: Test files in the order they are started, the longest first, so that no long file is left for
#: the end of a parallel run (``--no-loadscope-reorder`` in ``pyproject.toml`` keeps this order).
#: Seconds per file: ``GRASP_JAX_PROFILE_COMPILES`` (below) and ``tests/_profile.py``. Files not
#: named here follow, in their usual order; the tests of a file keep theirs.
LONGEST_FIRST = (
    "test_friction.py", "test_dtypes.py", "test_hands.py", "test_dataset.py", "test_docs.py", "test_contact.py",
    "test_robust.py", "test_objectives.py", "test_cli.py", "test_closure.py", "test_surfaces.py", "test_optimize.py",
    "test_batching.py", "test_robust_jaws.py", "test_pipeline.py", "test_devices.py", "test_lp.py", "test_html.py",
    "test_grippers.py", "test_compose.py", "test_cli_robust.py", "test_autodiff.py", "test_invariance.py",
    "test_crossover.py", "test_geometry.py", "test_cli_optimize.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: files stay whole


def _memory_maps() -> int:
    """Memory maps of this process (0 where ``/proc`` has no such file)."""
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def _max_memory_maps() -> int:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530


#: XLA's CPU executables hold memory maps (their JIT code) for as long as they live (a chunk
#: program of the library about 1,100 to 1,300), and a test worker keeps every program it compiled:
#: one reached Linux's ``vm.max_map_count`` (65,530) 93% through the suite, and the next compile
#: died inside XLA (segmentation faults and aborts in ``backend_compile_and_load``, three runs in a
#: row; ``tests/test_friction.py`` alone grows to 13,000 maps). Past half the limit, when a test
#: module ends, JAX's caches are cleared (the programs the tests jit themselves) and the library's
#: chunk programs are dropped, the least recently used first, until the maps are down to
#: :data:`KEEP_MEMORY_MAPS`: the programs many modules use (4-finger ``evaluate``, ...) stay, and a
#: later module compiles again only what it needs of the others.
MAX_MEMORY_MAPS = _max_memory_maps() // 2
#: ... and the maps left after the release: three quarters of that.
KEEP_MEMORY_MAPS = MAX_MEMORY_MAPS * 3 // 4
#: Memory maps of a chunk program, about (to drop several at a time between garbage collections).
MAPS_PER_PROGRAM = 1000


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    if _memory_maps() <= MAX_MEMORY_MAPS:
        return
    from grasp_jax import _batch

    jax.clear_caches()
    gc.collect()
    while (maps := _memory_maps()) > KEEP_MEMORY_MAPS:
        with _batch._LOCK:  # the least recently used first (the dict's order)
            oldest = list(_batch._PROGRAMS)[: 1 + (maps - KEEP_MEMORY_MAPS) // MAPS_PER_PROGRAM]
            for key in oldest:
                del _batch._PROGRAMS[key]
        gc.collect()
        if not oldest:
            break


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of the shared data folder; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def mesh_dir(shared_data) -> Path:
    path = shared_data / "meshes"
    if not path.is_dir():
        pytest.skip(f"shared meshes not found at {path}")
    return path


def _session_folder(basetemp: Path) -> Path:
    """This run's cache folder: beside the workers' base folders (``popen-gw0``, ...), or in the
    base folder of a run without workers."""
    return (basetemp.parent if os.environ.get("PYTEST_XDIST_WORKER") else basetemp) / "xla-cache"


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory):
    """Points ``GRASP_JAX_CACHE`` at this run's folder (the default; see the docstring)."""
    if SESSION_CACHE is not None:
        folder = SESSION_CACHE if SESSION_CACHE != "new" else str(_session_folder(tmp_path_factory.getbasetemp()))
        os.environ["GRASP_JAX_CACHE"] = os.environ[SESSION] = folder
    yield


def pytest_unconfigure(config):
    """The run's cache folder removed by the process that made it (the controller of the workers)."""
    if SESSION_CACHE == "new" and not os.environ.get("PYTEST_XDIST_WORKER"):
        factory = getattr(config, "_tmp_path_factory", None)
        if factory is not None:
            shutil.rmtree(_session_folder(factory.getbasetemp()), ignore_errors=True)


@pytest.fixture(scope="session")
def xla_cache(tmp_path_factory, _session_cache) -> str:
    """``GRASP_JAX_CACHE`` for the processes a test starts: the run's folder or the developer's,
    or, where the cache is switched off, one for this worker's processes (so that only the first
    of them compiles)."""
    if SESSION_CACHE is not None:
        return os.environ[SESSION]
    return SUITE_CACHE or str(tmp_path_factory.getbasetemp() / "xla-cache")


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, fresh for every test."""
    return np.random.default_rng(20240611)


@pytest.fixture
def in_process(monkeypatch, tmp_path):
    """``grasp-jax`` run in this process (its SIGTERM handler undone afterwards)."""
    from grasp_jax import cli

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.chdir(tmp_path)
    yield cli.main
    signal.signal(signal.SIGTERM, before)


@pytest.fixture
def usage(in_process, capsys):
    """``grasp-jax ARGS`` in this process, for the usage errors (exit 2 before any grasp is made),
    with the ``returncode``, ``stdout`` and ``stderr`` of ``test_cli.grasp_jax``: a process
    start each is what they cost. ``main``'s exit 2 in a real process: ``test_cli.py``'s
    ``test_user_mistakes_in_a_process``; ``dataset`` in one: ``test_killed_and_resumed_from_the_command_line``."""

    def run(*args):
        code = in_process([str(a) for a in args])
        out = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)

    return run


# ---------------------------------------------------------------------------------------------
# Opt-in profile of the compilations: GRASP_JAX_PROFILE_COMPILES=compiles.json writes, per test
# (setup, call and teardown together), its wall seconds, the number of XLA compilations, their
# backend-compile seconds and the programs (name, argument shapes, seconds); one file per worker
# (``compiles.gw0.json``, ...), and one line per test as it finishes (``compiles.gw0.jsonl``).
# ``python tests/_profile.py compiles.*.jsonl`` sums them up.
# ---------------------------------------------------------------------------------------------
PROFILE_COMPILES = os.environ.get("GRASP_JAX_PROFILE_COMPILES")


class _CompileProfile:
    def __init__(self):
        import logging
        import re
        import time

        self._time = time
        self.current = None  # the running test's record
        self.tests: list[dict] = []
        self._shapes = None
        self._compiling = re.compile(r"Compiling (\S+) with global shapes and types (.*?)\. Argument mapping")
        self._finished = re.compile(r"Finished XLA compilation of (\S+) in ([0-9.eE+-]+) sec")
        profile = self

        class Handler(logging.Handler):
            def emit(self, record):
                try:
                    message = record.getMessage()
                except Exception:  # noqa: BLE001
                    return
                profile._log(message)

        handler = Handler(level=logging.DEBUG)
        for name in ("jax._src.interpreters.pxla", "jax._src.dispatch"):
            logger = logging.getLogger(name)
            logger.setLevel(logging.DEBUG)
            logger.addHandler(handler)
        jax.monitoring.register_event_duration_secs_listener(self._event)

    def _event(self, event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration" and self.current is not None:
            self.current["compiles"] += 1
            self.current["compile_s"] += float(duration)

    def _log(self, message):
        if self.current is None:
            return
        match = self._compiling.search(message)
        if match:
            self._shapes = match.group(2)[:400]
            return
        match = self._finished.search(message)
        if match:
            self.current["programs"].append([match.group(1), self._shapes, float(match.group(2))])
            self._shapes = None

    def start(self, nodeid):
        self.current = {"test": nodeid, "compiles": 0, "compile_s": 0.0, "programs": [],
                        "start": self._time.time()}
        self._perf = self._time.perf_counter()

    def stop(self):
        import json

        self.current["wall_s"] = self._time.perf_counter() - self._perf
        self.tests.append(self.current)
        with open(_profile_path(".jsonl"), "a") as f:  # as it goes: a run cut short keeps its tests
            f.write(json.dumps({"worker": _worker(), **self.current}) + "\n")
        self.current = None


_PROFILE = _CompileProfile() if PROFILE_COMPILES else None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if _PROFILE is None:
        yield
        return
    _PROFILE.start(item.nodeid)
    try:
        yield
    finally:
        _PROFILE.stop()


def _worker():
    return os.environ.get("PYTEST_XDIST_WORKER")


def _profile_path(suffix):
    path = Path(PROFILE_COMPILES)
    worker = _worker()
    return path.with_name(f"{path.stem}.{worker}{suffix}" if worker else f"{path.stem}{suffix}")


def pytest_sessionfinish(session, exitstatus):
    if _PROFILE is None or (_worker() is None and getattr(session.config.option, "numprocesses", None)):
        return  # off, or the controller of an xdist run (the workers write)
    import json

    _profile_path(".json").write_text(json.dumps({"worker": _worker(), "tests": _PROFILE.tests}, indent=0))
