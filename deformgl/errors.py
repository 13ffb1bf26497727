"""Exceptions deformgl raises on purpose.

Every error a user can cause is a :class:`DeformglError`; the CLI prints its message on one line
and exits non-zero. Messages name the file and the key, vertex or node that is wrong.
"""

from __future__ import annotations


class DeformglError(Exception):
    """Base class: an error with a message meant for the user, printed without a traceback."""


class InputError(DeformglError):
    """Bad input: a mesh, scene or node file that cannot be used as given."""


class ArgumentError(InputError, ValueError):
    """A bad argument to a public API function (``ElasticMaterial``, ``Body.from_arrays``,
    ``make_simulation``, ...): the message has the form ``"<function>: <argument>: <what is
    wrong>"``, naming the argument as the caller passed it (a scene file names its key instead).
    Also a :class:`ValueError`, as Python's own argument checks are."""


class SceneError(InputError):
    """A scene file key that is unknown, of the wrong type, or has an impossible value.

    The message has the form ``"<file>: <key.path>: <what is wrong>"``; ``key`` and ``reason``
    hold its two last parts where the schema found it (None otherwise), so that a caller that set
    the key itself (the CLI's ``--set``) can blame its own flag.
    """

    def __init__(self, message: str, *, key: str | None = None, reason: str | None = None) -> None:
        super().__init__(message)
        self.key = key
        self.reason = reason


class GLError(DeformglError):
    """The OpenGL context could not be created or lacks a required capability."""


class ShaderError(DeformglError):
    """A shader file could not be preprocessed or compiled, or a uniform name is wrong."""


class SimulationError(DeformglError):
    """The simulation produced non-finite values or was asked for something it cannot do."""


class RefusedStepError(SimulationError, InputError):
    """A time step the integrator cannot run stably, refused before any work (the scene's or the
    caller's dt is the input at fault: the CLI exits 2)."""


class DeformglWarning(UserWarning):
    """Something deformgl worked around (a bad cache entry rebuilt, caching off): the CLI prints
    it as one line ``deformgl: warning: ...``; the work goes on."""
