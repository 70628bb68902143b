"""dejax.compile_cache: content keys, source digests and the exported-program cache (a
second process loads a traced program instead of tracing it again)."""
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import compile_cache


class _Scaled(eqx.Module):
    a: jax.Array
    power: int = eqx.field(static=True)

    def __call__(self, x):
        return self.a * x ** self.power


def test_content_digest_tells_array_values_and_static_fields_apart():
    d = compile_cache.content_digest
    assert d(_Scaled(jnp.asarray([1.0, 2.0]), 2)) == d(_Scaled(jnp.asarray([1.0, 2.0]), 2))
    assert d(_Scaled(jnp.asarray([1.0, 2.0]), 2)) != d(_Scaled(jnp.asarray([1.0, 2.5]), 2))  # same shapes, other values
    assert d(_Scaled(jnp.asarray([1.0, 2.0]), 2)) != d(_Scaled(jnp.asarray([1.0, 2.0]), 3))  # a static field


def test_source_digest_changes_with_the_code(tmp_path, monkeypatch):
    import types

    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("x = 1\n")
    mod = types.SimpleNamespace(__file__=str(pkg / "__init__.py"))
    before = compile_cache.source_digest(mod)
    assert compile_cache.source_digest(mod) == before
    (pkg / "__init__.py").write_text("x = 2\n")
    assert compile_cache.source_digest(mod) != before


def test_exported_call_saves_then_loads_the_program(tmp_path, monkeypatch):
    monkeypatch.setenv("DEJAX_CACHE_DIR", str(tmp_path))
    fn = jax.jit(lambda x, d: {"y": jnp.sin(x) * d["w"]})
    args = (jnp.linspace(0.0, 1.0, 5), {"w": jnp.asarray(3.0)})
    before = jax.config.jax_compilation_cache_dir
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        assert compile_cache.exported_call(fn, args, "k") is fn  # cache off: the function itself
        compile_cache.enable(tmp_path / "jax")
        first = compile_cache.exported_call(fn, args, "k")
        files = list((tmp_path / "exported").glob("*.jaxexport"))
        assert first is not fn and len(files) == 1
        second = compile_cache.exported_call(fn, args, "k")  # loaded from the file
        np.testing.assert_allclose(second(*args)["y"], fn(*args)["y"], rtol=0, atol=0)
        np.testing.assert_allclose(first(*args)["y"], fn(*args)["y"], rtol=0, atol=0)
        compile_cache.exported_call(fn, args, "another program")
        compile_cache.exported_call(fn, (jnp.linspace(0.0, 1.0, 6), args[1]), "k")  # other shapes
        assert len(list((tmp_path / "exported").glob("*.jaxexport"))) == 3
        files[0].write_bytes(b"damaged")
        assert compile_cache.exported_call(fn, args, "k") is fn  # a damaged file: traced as usual
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
