"""The path not taken: the loop remembers the first close runner-up and, at the end, walks
that branch and keeps the better ending (``LoopOptions.revisit``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from copy import copy
from typing import Any

from hhra_phys.diagnosis.selection import Step, information_criterion, tie_break

__all__ = []


def _shallow(v: Any) -> Any:
    """A list or dict copied one level deep (a loop path's own containers), else ``v``."""
    return list(v) if isinstance(v, list) else dict(v) if isinstance(v, dict) else v


class _RevisitStage:
    """The path not taken, of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin of its state)."""

    def _snapshot(self) -> dict[str, Any]:
        return {k: _shallow(getattr(self, k)) for k in self._PATH}

    def _restore(self, state: Mapping[str, Any]) -> None:
        for k, v in state.items():
            setattr(self, k, _shallow(v))

    def _remember_branch(self, rnd: int, best: Step, tried: list[tuple[Step, Any]],
                         noise: float, judged: Mapping[int, str] | None = None) -> None:
        """Before ``best`` is accepted: keep the path of the best given effect it beat
        (``judged``: each step's reason before :func:`choose` added its verdict)."""
        if not self.o.revisit or self.branch is not None or not best.discovered:
            return
        given = [(s, p) for s, p in tried if not s.discovered]
        if not given:
            return
        k = tie_break([(float(s.val.get("rmse", math.inf)), s.criterion) for s, _ in given],
                      noise, self.tol)
        step = given[k][0]
        self.branch = {"round": rnd, "step": step, "payload": given[k][1],
                       "instead_of": best, "noise": noise, "state": self._snapshot(),
                       "judged": (judged or {}).get(id(step), step.reason)}

    def _branch_stands(self) -> bool:
        """Whether the path not taken is still worth following: the discovered candidate
        that took the branch round, or any other stand-in (a discovered term or mode, a
        sensor's effect), is in this path's final model.

        Once the backward step removed the discovered winner (or its library form replaced
        it) and the model holds given effects of the dynamics only, this path has undone
        the greedy choice itself, and following the other costs a second loop for the same
        physics: on a 25 s drive record a pair of the friction and the force offset came in
        round 2 beside the discovered term of round 1, which the backward step then
        removed, and the revisited path from the dead zone ended with the same two effects
        (selection 1.014e-6 against 1.02e-6 m) at twice the loop's cost. Where a stand-in
        remains, the other path may not hold it: on another seed the first path ended with
        a sensor offset beside the friction and the force, which its revisit had avoided.
        """
        br = self.branch
        if br is None or br["instead_of"].effect in self.chosen:
            return True
        stand_ins = [n for n in self.chosen if self._stand_in(n)]
        if stand_ins:
            return True
        self.revisit_skipped = (f"not revisited: {br['instead_of'].effect}, which took round "
                                f"{br['round']} from {br['step'].effect}, is no longer in the "
                                f"model, which holds given effects of the dynamics only "
                                f"({', '.join(self.chosen) or 'nothing'})")
        self.say(f"revisit: {self.revisit_skipped}")
        return False

    def _stand_in(self, name: str) -> bool:
        """Whether the chosen effect ``name`` is a stand-in: a discovered term or mode, or a
        sensor's effect (by the step that added it; unknown: a stand-in)."""
        step = self._accepted_step(name)
        return step is None or step.discovered or step.sensor

    def _revisit(self) -> None:
        """Follow the path of the given effect a discovered candidate won over; keep the
        better final model by the rule (:attr:`LoopOptions.revisit`)."""
        br, say = self.branch, self.say
        assert br is not None
        first = self._snapshot()
        first_sel = float(self.cur.metrics["val"]["rmse"])
        first_crit = information_criterion(self.cur, self.o.criterion)
        self._restore(br["state"])
        # The two steps of the branch round are copied: the first path keeps its own.
        alt, was = copy(br["step"]), copy(br["instead_of"])
        alt.notes, was.notes = list(alt.notes), list(was.notes)
        self.steps = [alt if s is br["step"] else was if s is br["instead_of"] else s
                      for s in self.steps]
        rnd = br["round"]
        say(f"revisit: the loop ended above the noise level after {was.effect} took round "
            f"{rnd} from {alt.effect}; following the path from {alt.effect}")
        alt.accepted, was.accepted = True, False
        # its reason said why it lost the round to `was`; what it was judged on stays
        alt.reason = f"accepted on revisiting round {rnd}: {br['judged']}"
        self._accept(rnd, alt, br["payload"])
        self._rounds(rnd)
        alt_sel = float(self.cur.metrics["val"]["rmse"])
        alt_crit = information_criterion(self.cur, self.o.criterion)
        keep_alt = tie_break([(first_sel, first_crit), (alt_sel, alt_crit)], br["noise"],
                             self.tol) == 1
        summary = (f"path from {was.effect}: selection RMSE {first_sel:.4g}, "
                   f"{self.o.criterion.upper()} {first_crit:.1f} ({', '.join(first['chosen'])})"
                   f"; path from {alt.effect}: {alt_sel:.4g}, {alt_crit:.1f} "
                   f"({', '.join(self.chosen)})")
        self.revisited = {"round": rnd, "instead_of": was.effect, "alternative": alt.effect,
                          "first": {"val_rmse": first_sel, "criterion": first_crit,
                                    "chosen": list(first["chosen"])},
                          "alternative_path": {"val_rmse": alt_sel, "criterion": alt_crit,
                                               "chosen": list(self.chosen)},
                          "kept": "alternative" if keep_alt else "first"}
        if keep_alt:
            was.reason = (f"accepted, then replaced on revisiting round {rnd} (the rule "
                          f"prefers the path from {alt.effect}: {summary}): {was.reason}")
            say(f"revisit: kept the path from {alt.effect} ({summary})")
        else:
            self._restore(first)
            br["instead_of"].notes.append(f"revisited round {rnd}, path kept: {summary}")
            say(f"revisit: kept the path from {was.effect} ({summary})")
