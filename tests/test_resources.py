"""The GL owner base: roll-back on a half-built constructor, idempotent release, ``with``."""

import moderngl
import pytest

from deformgl.gl.resources import GLOwner, is_released, restore_framebuffer


class _TwoTextures(GLOwner):
    def __init__(self, ctx, fail: bool):
        super().__init__(ctx)
        with self.building():
            self.a = self.own(ctx.texture((2, 2), 4, dtype="f4"))
            self.b = self.own(ctx.texture((2, 2), 4, dtype="f4"))
            if fail:
                raise ValueError("half-way")


def test_failed_constructor_releases_what_it_made(ctx, monkeypatch):
    made = []
    original = ctx.texture

    def texture(*args, **kwargs):
        made.append(original(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(ctx, "texture", texture)
    with pytest.raises(ValueError, match="half-way"):
        _TwoTextures(ctx, fail=True)
    assert len(made) == 2 and all(is_released(t) for t in made)


def test_release_is_idempotent_and_newest_first(ctx):
    order = []

    class Probe:
        def __init__(self, name):
            self.name = name

        def release(self):
            order.append(self.name)

    owner = GLOwner(ctx)
    for name in "abc":
        owner.own(Probe(name))
    assert owner.owned_count == 3
    owner.release()
    owner.release()
    assert order == ["c", "b", "a"] and owner.released and owner.owned_count == 0
    with pytest.raises(RuntimeError, match="released"):
        owner.own(Probe("d"))


def test_with_releases(ctx):
    with _TwoTextures(ctx, fail=False) as owner:
        assert not is_released(owner.a)
    assert is_released(owner.a) and is_released(owner.b)


def test_release_goes_on_after_a_failure(ctx):
    class Bad:
        def release(self):
            raise moderngl.Error("boom")

    owner = GLOwner(ctx)
    tex = owner.own(ctx.texture((2, 2), 4, dtype="f4"))
    owner.own(Bad())
    with pytest.raises(moderngl.Error, match="boom"):
        owner.release()
    assert is_released(tex)


def test_restore_framebuffer(ctx):
    tex = ctx.texture((2, 2), 4, dtype="f4")
    fbo = ctx.framebuffer([tex])
    other = ctx.framebuffer([ctx.texture((2, 2), 4, dtype="f4")])
    other.use()
    restore_framebuffer(ctx, fbo)
    assert ctx.fbo == fbo
    fbo.release()
    restore_framebuffer(ctx, fbo)
    assert ctx.fbo.glo == 0
    other.release()
    tex.release()
