"""Which solve control/aware.py's scheme returns, and whether its next solve is a draft.

The scheme's solves each keep a margin (slider - height, per constraint sample) and have a
residual, their own Monte-Carlo's tightening less that margin. A solve settles where every
residual is within the tolerance, or where it sits on the safe side of a jump: residual <= 0
where some solve, draft or full, at a margin within the tolerance had a residual more than the
tolerance above it and above -tolerance, i.e. the map rose by more than the tolerance into the
tolerance's band (or across it) within less than the tolerance of margin (control/aware.py's
docstring has the models this was seen on).

A full solve that settles is returned; so is a draft that settles where its states are its
torque's own (`exact`: it kept its warm start's 2 pi crossing, so the NLP's states are the
mean model's rollout of its torque, to the bit on the bench's models): it meets every
constraint of the NLP to FEASIBILITY_TOLERANCE and its Monte-Carlo is its torque's, so it is a
solution of the same fixed point, to IPOPT's draft tolerance rather than the full solve's. A
draft that settles where its crossing moved (its states are then its torque's rollout, not the
NLP's) is followed once by a draft with each theta_k bounded to the turn that rollout puts it
on (`bounded`; exact by its bounds), returned if it settles; otherwise full solves follow. A
full solve on the safe side everywhere but with more slack than the tolerance and no such rise
is held, and a draft from it probes for one: where the draft shows it, the held solve is
returned; otherwise a full solve follows from the held one. A solve that comes back, unsettled,
to an earlier one of its kind is cycling (`repeats`).
"""

from __future__ import annotations

from typing import Generic, TypeVar

import numpy as np

Payload = TypeVar("Payload")


class Acceptance(Generic[Payload]):
    """Which solve the scheme returns, and whether the next solve is a draft (module
    docstring): `take` each solve's margin and residual (tightening - margin, per constraint
    sample) with what to return for it; it answers that payload, a held one, or None."""

    def __init__(self, tolerance: float, *, draft: bool = True) -> None:
        self.tolerance = tolerance
        self.draft = draft
        """Whether the next solve is a draft (`draft`: the first one)."""
        self.start: Payload | None = None
        """The solve the next one starts from, where it is not the one just taken (a held
        full solve, after a probe that showed no jump)."""
        self._seen: list[tuple[bool, np.ndarray, np.ndarray]] = []
        """Every solve taken: whether a draft, its margin, its residual."""
        self._held: tuple[np.ndarray, np.ndarray, Payload] | None = None
        self.bounded = False
        """Whether the next solve is a draft with each theta_k bounded to its warm start's
        turn: once, after a draft that settled where its crossing moved."""
        self._bounded_once = False

    def settled(self, margin: np.ndarray, residual: np.ndarray) -> bool:
        """Within the tolerance at every sample, or on the safe side of a jump there: residual
        <= 0 where a solve taken so far, at a margin within the tolerance, had a residual above
        -tolerance and more than the tolerance above this one (module docstring)."""
        tol = self.tolerance
        near = np.abs(residual) < tol
        jumped = np.zeros_like(near)
        for _, other_margin, other_residual in self._seen:
            rose = (other_residual > -tol) & (other_residual - residual > tol)
            jumped |= rose & (np.abs(margin - other_margin) < tol)
        return bool((near | (jumped & (residual <= 0))).all())

    def cycling(self) -> bool:
        """Whether the solve taken last, unsettled, came back to an earlier one (`repeats`)."""
        *before, (draft, margin, residual) = self._seen
        return repeats(before, draft, margin, residual, tolerance=self.tolerance)

    def take(
        self,
        margin: np.ndarray,
        residual: np.ndarray,
        payload: Payload,
        *,
        exact: bool = False,
        moved: bool = False,
    ) -> Payload | None:
        """Take the solve just made (a draft if `self.draft` was; `exact`: a draft whose states
        are its torque's own; `moved`: a draft whose crossing moved): `payload` if it is a full
        solve that settled, or an exact draft that settled while no full solve is held, a held
        full solve's payload if this solve showed the jump it sat by, else None, with
        `self.draft`, `self.bounded` and `self.start` set for the next solve."""
        draft, self.bounded = self.draft, False
        # a draft while a solve is held is its probe: holding is the only way back to drafts
        # once a full solve was made, and the probe's answer always leaves the drafts
        probed = self._held if draft else None
        self.start = None
        self._seen.append((draft, margin, residual))
        final = not draft or (exact and probed is None)
        if final and self.settled(margin, residual):
            return payload
        if self._held is not None and self.settled(*self._held[:2]):
            return self._held[2]
        if probed is not None:  # no jump: a full solve from the held one
            self.draft, self.start = False, probed[2]
            return None
        safe = bool(np.all((residual <= 0) | (np.abs(residual) < self.tolerance)))
        if not draft and safe:  # its slack may be a jump's: a draft from it probes it
            self._held, self.draft = (margin, residual, payload), True
        elif moved and not self._bounded_once and self.settled(margin, residual):
            self.bounded = self._bounded_once = True  # a draft on its torque's own turns
        else:
            self.draft = draft and not self.settled(margin, residual)
        return None


def repeats(
    seen: list[tuple[bool, np.ndarray, np.ndarray]],
    draft: bool,
    margin: np.ndarray,
    residual: np.ndarray,
    *,
    tolerance: float,
) -> bool:
    """Whether an unsettled solve (a draft or not, its margin and residual per constraint
    sample) came back: within `tolerance` in both of one of the same kind made before the last
    one (`seen`, oldest first), the last one not (it went away). The scheme is then cycling
    (module docstring), and each further solve would go round again; a scheme that creeps,
    each solve within the tolerance of the one before, is left to settle."""

    def near(other: tuple[np.ndarray, np.ndarray]) -> bool:
        apart = np.maximum(np.abs(margin - other[0]), np.abs(residual - other[1]))
        return bool(np.all(apart < tolerance))

    if not seen or near(seen[-1][1:]):
        return False
    return any(kind == draft and near((other, rest)) for kind, other, rest in seen[:-1])
