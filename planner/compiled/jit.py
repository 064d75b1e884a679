"""numba's ``njit`` for the compiled kernels, with a machine-code cache that can always be written.

numba keeps compiled kernels next to their source, else in the user's cache directory; where
neither is writable (a read-only install run by a user without a home) it refuses to define a
cached function at import. Then the cache goes to the temporary directory instead, before numba
reads its configuration. ``NUMBA_CACHE_DIR`` set by the user always wins.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            return True
    except OSError:
        return False


if "NUMBA_CACHE_DIR" not in os.environ:
    here = Path(__file__).resolve().parent / "__pycache__"
    if not _writable(here) and not _writable(Path.home() / ".cache" / "numba"):
        os.environ["NUMBA_CACHE_DIR"] = str(Path(tempfile.gettempdir()) / f"regrasp-numba-{os.getuid()}")

from numba import njit  # after the cache directory is settled

__all__ = ["njit"]
