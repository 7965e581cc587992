"""The per-solve workspace: everything an evaluation may keep between calls, off the model.

The compiled model is immutable (MuJoCo's ``mjModel``/``mjData`` split); what evaluating it
fills in and reuses lives here, one :class:`Workspace` per solve (``SolveData`` owns one and
passes it to every evaluation): the assembler's value buffers and the column-ordered layout
of its pattern, the families tiled across ``F`` frames (:mod:`poise.model.frame_batch`),
motion targets per time and the integrals of velocity / acceleration motions, analytic curves'
tiled programs. Entries are kept per owning object (by identity); an evaluation without a
workspace gets a fresh one, so nothing outlives the call.
"""
from __future__ import annotations


class Workspace:
    """Scratch of one solve (see the module docstring).

    :meth:`scratch` gives each owner (an assembler, a model, a kernel's data object) its own
    object, created by ``factory()`` on first use and kept for the solve.
    """

    __slots__ = ("_scratch",)

    def __init__(self):
        self._scratch: dict[int, tuple] = {}

    def scratch(self, owner, factory):
        """The scratch object of ``owner`` (created by ``factory()`` on first use)."""
        hit = self._scratch.get(id(owner))
        if hit is None or hit[0] is not owner:
            hit = self._scratch[id(owner)] = (owner, factory())
        return hit[1]

    def clear(self) -> None:
        """Forget everything kept (memory; the next evaluations rebuild what they need)."""
        self._scratch.clear()
