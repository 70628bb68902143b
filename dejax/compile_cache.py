"""JAX's persistent compilation cache for dejax commands.

A second identical ``dejax`` command loads its compiled programs from disk instead of
compiling them again. On by default for the command line, in ``$DEJAX_CACHE_DIR`` or
``$XDG_CACHE_HOME/dejax/jax`` (``~/.cache/dejax/jax``); off with ``--no-compile-cache``
or ``DEJAX_COMPILE_CACHE=0``. Library use (``import dejax``) leaves JAX's setting alone:
call ``enable()`` to opt in. Programs with host callbacks (the sparse solver) are not
cacheable by JAX and compile as before.

The persistent cache skips XLA's compilation, not Python's tracing of the program;
``exported_call`` skips that too, for programs of plain arrays (fits): the traced
program is exported (``jax.export``, serialized with ``flatbuffers``) to
``cache_root()/exported`` under a content key and loaded by later processes.
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


def enabled() -> bool:
    """Whether JAX's persistent compilation cache is on (``enable()`` or JAX's own setting)."""
    return bool(jax.config.jax_compilation_cache_dir)


def source_digest(*packages) -> str:
    """sha256 of the source files (``*.py``) of the given imported packages: a key part that
    changes with any edit of the code a traced program came from."""
    import hashlib

    h = hashlib.sha256(jax.__version__.encode())
    for pkg in packages:
        for path in sorted(Path(pkg.__file__).parent.rglob("*.py")):
            h.update(str(path.relative_to(Path(pkg.__file__).parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def content_digest(obj) -> str:
    """sha256 of a pytree's structure (static fields included) and of its leaves' values:
    equal digests mean equal objects for the program they are closed over in."""
    import hashlib

    import numpy as np

    leaves, treedef = jax.tree_util.tree_flatten(obj)
    h = hashlib.sha256(str(treedef).encode())
    for leaf in leaves:
        if isinstance(leaf, (jax.Array, np.ndarray, np.generic, float, int, complex, bool)):
            a = np.asarray(leaf)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(leaf).encode())
    return h.hexdigest()


def exported_call(fn, args: tuple, key: str):
    """``fn`` (a jitted function of array pytrees of builtin containers) as a callable that
    skips Python tracing when the same program was traced before: with the compilation
    cache on, the program is exported (``jax.export``) once to ``cache_root()/exported``
    under ``key`` + the argument shapes and dtypes, and later processes deserialize it (its
    XLA compilation then comes from the compilation cache). ``key`` must determine the
    program: the static configuration and ``source_digest`` of the code it comes from.
    Without the cache, or when the program cannot be exported, ``fn`` itself."""
    import hashlib

    from jax import export

    if not enabled():
        return fn
    avals = jax.tree_util.tree_map(lambda a: (tuple(jax.numpy.shape(a)), str(jax.numpy.result_type(a))), args)
    where = f"{jax.__version__}|{jax.default_backend()}|{jax.config.jax_enable_x64}"
    digest = hashlib.sha256(f"{key}|{where}|{jax.tree_util.tree_structure(args)}|{avals}".encode()).hexdigest()
    path = cache_root() / "exported" / f"{digest}.jaxexport"
    try:
        if path.exists():
            return export.deserialize(bytearray(path.read_bytes())).call
        exp = export.export(fn)(*args)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(exp.serialize())
        tmp.replace(path)
        return exp.call
    except Exception:  # not exportable (host callbacks, unregistered pytrees) or a damaged file
        return fn
