"""JAX's persistent compilation cache for dejax commands.

A second identical ``dejax`` command loads its compiled programs from disk instead of
compiling them again. On by default for the command line, in ``$DEJAX_CACHE_DIR`` or
``$XDG_CACHE_HOME/dejax/jax`` (``~/.cache/dejax/jax``); off with ``--no-compile-cache``
or ``DEJAX_COMPILE_CACHE=0``. Library use (``import dejax``) leaves JAX's setting alone:
call ``enable()`` to opt in. Programs with host callbacks (the sparse solver) are not
cacheable by JAX and compile as before.
"""
from __future__ import annotations

import os
from pathlib import Path

import jax


def cache_root() -> Path:
    """dejax's cache folder: ``$DEJAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/dejax`` (``~/.cache/dejax``)."""
    if os.environ.get("DEJAX_CACHE_DIR"):
        return Path(os.environ["DEJAX_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dejax"


def default_dir() -> Path:
    """The compilation cache: ``$DEJAX_CACHE_DIR`` itself, else ``cache_root() / "jax"``."""
    if os.environ.get("DEJAX_CACHE_DIR"):
        return cache_root()
    return cache_root() / "jax"


def disabled_by_env() -> bool:
    return os.environ.get("DEJAX_COMPILE_CACHE", "1").strip().lower() in ("0", "false", "no", "off")


def enable(path: str | Path | None = None) -> Path | None:
    """Turn the cache on in ``path`` (default ``default_dir()``); returns the folder, or
    None when it cannot be created (the run then compiles as usual)."""
    folder = Path(path) if path is not None else default_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder
