"""Shared test set-up: strict JAX promotion rules and common fixtures."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

# Catch accidental broadcasting of mismatched ranks inside the library.
jax.config.update("jax_numpy_rank_promotion", "raise")

from helpers import MESHES, SCENES  # noqa: E402

from jaxlc.xla import enable_persistent_cache  # noqa: E402

# Compile into jaxlc's persistent cache from the first test, as `jaxlc fit` and
# `jaxlc generate` do (until one of them ran in-process, every test compiled afresh):
# ~40 % of a cold suite is XLA compilation (692 of 1,720 s measured), which a second
# `make test` on the same machine then loads instead; `JAXLC_XLA_CACHE=off` turns it
# off, `JAXLC_CACHE_DIR` moves it. Results do not depend on it: JAX keys each entry by
# the computation, the compile options and its own version.
enable_persistent_cache()

#: Most memory mappings the test process may hold before compiled code is freed.
#: Each XLA CPU executable holds ~6 mappings while JAX's caches keep it alive, and
#: the suite compiles ~10⁴ of them in this one process. At the kernel's
#: ``vm.max_map_count`` (65,530) XLA's next mmap fails, and the C++ error it raises
#: crashed the process in the unwinder (a segfault at 91 % of the suite, in CI too;
#: the count was 65,315 ten seconds before). Freeing between modules keeps it bounded.
MAX_MAPPINGS = 20_000


def _mappings() -> int:
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux
        return 0


@pytest.fixture(autouse=True, scope="module")
def _bounded_compiled_code():
    """After each test module, free compiled code once it holds too many mappings."""
    yield
    if _mappings() > MAX_MAPPINGS:
        jax.clear_caches()


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    return SCENES


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    return MESHES


@pytest.fixture
def write_scene(tmp_path):
    """Write a scene TOML text to a file next to a copy-free mesh reference."""

    def _write(text: str, name: str = "scene.toml") -> Path:
        path = tmp_path / name
        path.write_text(text.replace("@MESHES@", str(MESHES)))
        return path

    return _write
