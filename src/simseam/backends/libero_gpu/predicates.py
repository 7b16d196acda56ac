"""LIBERO's BDDL goal predicates, written once over N worlds (issue 38, item 5).

API (stable; ``state.py`` documents ``LiberoState``)::

    from simseam.backends.libero_gpu.predicates import GoalCheck
    from simseam.backends.libero_gpu.state import LiberoState

    info = worker.call("describe", suite=..., task=...)          # libero_gpu.native, in LIBERO's venv
    check = GoalCheck.compile(label, info["goal"]["goal_state"], mjm, info["goal"]["objects"])
    state = LiberoState.from_cpu(mjm, [data])                    # or LiberoState.from_warp(mjm, warp_data)
    check.met(state)       # bool[N] (xp of the state): every goal predicate holds (LIBERO's _check_success)
    check.values(state)    # bool[N, P]: each predicate's truth, columns in goal order, named check.names[p]

- ``label``: how errors name the task (e.g. ``"LIBERO task libero_goal/3"``);
- ``goal_state``: LIBERO's parsed goal (``parsed_problem["goal_state"]``, e.g. ``[["on", "a_1", "plate_1"]]``):
  a conjunction, as LIBERO's ``_check_success`` reads it;
- ``mjm``: the task's ``MjModel`` (the one the state's worlds run; names are resolved in it, once);
- ``objects``: what LIBERO knows of each name in the goal (and each region's parent), as plain data made by the
  native worker (``native.goal_facts``): its kind (``object`` / ``fixture`` / ``site``), its root body or site,
  its contact geoms (robosuite's ``contact_geoms``), its joints, its category and articulation ranges (LIBERO's
  ``object_properties["articulation"]``), a region's size (LIBERO's ``SiteObject.size``) and parent.

When: LIBERO's episode success is ``_check_success()`` right after ``env.step``, on the poses and contacts the
step's last physics step computed before integrating (see ``state.py``): evaluate ``met`` on MuJoCo Warp's data
as ``step`` leaves it to reproduce that. The predicates read world poses from the data only (never the model's
``body_pos``), so fixtures placed per world through batched model fields are honoured. On MuJoCo Warp the state
is float32: a position within float32 rounding of a threshold may decide differently than LIBERO's float64.
``goal_replay.py`` checks the predicates against LIBERO itself (``benchmarks/libero_predicates_check.py``).

A predicate this module does not evaluate (or an argument LIBERO itself could not evaluate it on, e.g. ``Open``
of a movable object) is a one-line ``ConfigError`` naming the task and the predicate, raised by ``compile``.

Semantics (LIBERO's ``predicates/base_predicates.py`` and ``object_states/base_object_states.py``; positions are
an object's root body ``xpos`` or a region site's ``site_xpos``):

- ``On(a, b)``, ``b`` an object or fixture: ``b``'s z <= ``a``'s z, ``a`` and ``b`` in contact, and their
  horizontal distance < 0.03 m. ``b`` a region (site of pose ``p``, rotation ``R``, size ``s``): with
  ``d = R (a - p)`` (LIBERO's ``SiteObject.under``, R not transposed), ``s_z - 0.005 < d_z < s_z + 0.10`` and
  ``|d_x| < s_x``, ``|d_y| < s_y``; and, when the region has a parent object, the parent touches ``a``.
- ``In(a, b)``, ``b`` a region: with ``h = |R s|`` (elementwise), ``p - h - (0, 0, 0.01) < a < p + h`` in every
  axis, strictly (LIBERO's ``SiteObject.in_box``; a region's contact test is always true).
- ``Open(x)`` / ``TurnOn(x)``: some joint of ``x`` is open / on; ``Close(x)`` / ``TurnOff(x)``: every joint is
  closed / off (none: true). ``x`` an object or fixture: its joints and its category's rule; ``x`` a region:
  the joints LIBERO found for the region and its parent's rule. The rules (``RULES``) are each category's
  ``is_open`` / ``is_close`` / ``turn_on`` / ``turn_off``: a comparison with the min or max of a range.
- ``Up(x)``: ``x``'s z >= 1.0 m. ``true`` / ``false``: constants.

Contacts are robosuite's ``check_contact``: some active contact joins a geom of one set to a geom of the other.
All the goal's contact tests are reduced at once: a membership table (geom -> set) looked up for each contact,
then ``xp.bincount`` per world (no per-world control flow).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from simseam.seam.errors import ConfigError

ON_XY = 0.03  # m: On(a, object): horizontal distance between the two bodies
UNDER_BELOW = 0.005  # m: On(a, region): a's offset may sink this far under the region's half-height ...
UNDER_ABOVE = 0.10  # m: ... and rise this far above it
IN_BELOW = 0.01  # m: In(a, region): the box reaches this far under the region
UP_Z = 1.0  # m: Up(x)

#: each articulated category's rules: predicate -> (comparison, range, which end of the range)
_CABINET = {"open": ("<", "default_open_ranges", max), "close": (">", "default_close_ranges", min)}
_FRIDGE = {"open": (">", "default_open_ranges", min), "close": ("<", "default_close_ranges", max)}
_STOVE = {"turnon": (">=", "default_turnon_ranges", min), "turnoff": ("<", "default_turnoff_ranges", max)}
RULES = {"microwave": _CABINET, "wooden_cabinet": _CABINET, "white_cabinet": _CABINET, "yellow_cabinet": _CABINET,
         "short_cabinet": _FRIDGE, "short_fridge": _FRIDGE, "flat_stove": _STOVE, "yellow_stove": _STOVE}
#: Open / TurnOn hold when any joint does, Close / TurnOff when all do
JOINT_PREDICATES = {"open": "any", "close": "all", "turnon": "any", "turnoff": "all"}
PREDICATES = ("true", "false", "on", "in", "up", *JOINT_PREDICATES)


def shown(term: list) -> str:
    return "(" + " ".join(str(a) for a in term) + ")"


# --- compiled predicates: each (state, touch) -> bool[N]; touch: bool[N, T], the goal's contact tests ----------

@dataclass(frozen=True)
class _Const:
    value: bool

    def __call__(self, s, touch):
        return s.xp.full(s.num_worlds, self.value, dtype=bool)


@dataclass(frozen=True)
class _Point:
    """An object's root body (``body``) or a region's site (``site``): the position LIBERO reads."""

    body: int = -1
    site: int = -1

    def of(self, s):
        return s.xpos[:, self.body] if self.body >= 0 else s.site_xpos[:, self.site]


@dataclass(frozen=True)
class _OnObject:
    obj: _Point
    target: _Point
    test: int

    def __call__(self, s, touch):
        a, b = self.obj.of(s), self.target.of(s)
        near = s.xp.sqrt(((a[:, :2] - b[:, :2]) ** 2).sum(axis=1)) < ON_XY
        return (b[:, 2] <= a[:, 2]) & touch[:, self.test] & near


@dataclass(frozen=True)
class _OnRegion:
    obj: _Point
    site: int
    size: tuple[float, float, float]
    test: int  # the parent's contact test; -1: the region has no parent object

    def __call__(self, s, touch):
        xp = s.xp
        d = (s.site_xmat[:, self.site] @ (self.obj.of(s) - s.site_xpos[:, self.site])[:, :, None])[:, :, 0]
        size = xp.asarray(self.size, dtype=d.dtype)
        ok = (size[2] - UNDER_BELOW < d[:, 2]) & (d[:, 2] < size[2] + UNDER_ABOVE)
        ok = ok & (xp.abs(d[:, :2]) < size[:2]).all(axis=1)
        return ok & touch[:, self.test] if self.test >= 0 else ok


@dataclass(frozen=True)
class _InRegion:
    obj: _Point
    site: int
    size: tuple[float, float, float]

    def __call__(self, s, touch):
        xp = s.xp
        p, rot = s.site_xpos[:, self.site], s.site_xmat[:, self.site]
        half = xp.abs((rot @ xp.asarray(self.size, dtype=rot.dtype)[:, None])[:, :, 0])
        below = xp.asarray([0.0, 0.0, IN_BELOW], dtype=p.dtype)
        a = self.obj.of(s)
        return ((a > p - half - below) & (a < p + half)).all(axis=1)


@dataclass(frozen=True)
class _Up:
    point: _Point

    def __call__(self, s, touch):
        return self.point.of(s)[:, 2] >= UP_Z


@dataclass(frozen=True)
class _Joints:
    qpos: tuple[int, ...]
    op: str
    threshold: float
    reduce: str  # "any" | "all"

    def __call__(self, s, touch):
        xp = s.xp
        if not self.qpos:
            return xp.full(s.num_worlds, self.reduce == "all", dtype=bool)
        q = s.qpos[:, xp.asarray(np.asarray(self.qpos, np.int64))]
        hit = {"<": q < self.threshold, ">": q > self.threshold, ">=": q >= self.threshold}[self.op]
        return hit.any(axis=1) if self.reduce == "any" else hit.all(axis=1)


# --- compiling a goal ----------------------------------------------------------------------------------------

class _Builder:
    """Resolves one goal's names in the model, once; collects its contact tests (pairs of geom sets)."""

    def __init__(self, task: str, mjm: Any, objects: dict[str, dict[str, Any]]):
        self.task, self.mjm, self.objects = task, mjm, objects
        self.tests: list[tuple[tuple[int, ...], tuple[int, ...]]] = []

    def fail(self, term: list, why: str) -> ConfigError:
        return ConfigError(f"{self.task}: goal predicate {shown(term)}: {why}")

    def fact(self, term: list, name: str) -> dict[str, Any]:
        if name not in self.objects:
            raise self.fail(term, f"LIBERO's facts name no object or region {name!r}")
        return self.objects[name]

    def index(self, term: list, kind: str, name: str) -> int:
        try:
            return int(getattr(self.mjm, kind)(name).id)
        except KeyError:
            raise self.fail(term, f"no {kind} named {name!r} in the task's model") from None

    def point(self, term: list, name: str, movable: bool = False) -> _Point:
        f = self.fact(term, name)
        if f["kind"] == "site":
            if movable:
                raise self.fail(term, f"{name!r} is a region; LIBERO moves objects only")
            return _Point(site=self.index(term, "site", f["site"]))
        return _Point(body=self.index(term, "body", f["body"]))

    def test(self, term: list, a: str, b: str) -> int:
        """The contact test between two objects' contact geoms (robosuite's ``check_contact``)."""
        pair = tuple(tuple(sorted({self.index(term, "geom", g) for g in self.fact(term, n)["geoms"]})) for n in (a, b))
        if pair not in self.tests:
            self.tests.append(pair)
        return self.tests.index(pair)

    def term(self, term: list) -> Any:
        pred, args = term[0].lower(), term[1:]
        if pred not in PREDICATES:
            raise self.fail(term, f"not a predicate LIBERO on Warp evaluates ({', '.join(PREDICATES)})")
        arity = {"true": None, "false": None, "on": 2, "in": 2}.get(pred, 1)
        if arity is not None and len(args) != arity:
            raise self.fail(term, f"{pred} takes {arity} argument(s), got {len(args)}")
        if pred in ("true", "false"):
            return _Const(pred == "true")
        if pred == "up":
            return _Up(self.point(term, args[0]))
        if pred in JOINT_PREDICATES:
            return self.joints(term, pred, args[0])
        return self.on(term, *args) if pred == "on" else self.into(term, *args)

    def on(self, term: list, a: str, b: str) -> Any:
        obj, fb = self.point(term, a, movable=True), self.fact(term, b)
        if fb["kind"] != "site":
            return _OnObject(obj, self.point(term, b), self.test(term, a, b))
        if not fb.get("under", True):
            return _Const(True)  # LIBERO: a region without ``under`` holds anything on it
        parent = fb.get("parent")
        test = self.test(term, parent, a) if parent else -1
        return _OnRegion(obj, self.index(term, "site", fb["site"]), self.size(term, fb), test)

    def into(self, term: list, a: str, b: str) -> Any:
        obj, fb = self.point(term, a, movable=True), self.fact(term, b)
        if fb["kind"] != "site":
            raise self.fail(term, f"{b!r} is an object, not a region (In an object's own box is not evaluated)")
        return _InRegion(obj, self.index(term, "site", fb["site"]), self.size(term, fb))

    def size(self, term: list, fact: dict[str, Any]) -> tuple[float, float, float]:
        size = tuple(float(v) for v in np.asarray(fact["size"], float).ravel())
        if len(size) != 3:
            raise self.fail(term, f"region size {list(size)} is not 3 numbers")
        return size

    def joints(self, term: list, pred: str, name: str) -> _Joints:
        f = self.fact(term, name)
        owner = self.fact(term, f["parent"]) if f["kind"] == "site" and f.get("parent") else f
        category = owner.get("category")
        rule = RULES.get(category, {}).get(pred)
        if rule is None:
            raise self.fail(term, f"{name!r} (category {category!r}) has no {pred} rule in LIBERO")
        op, key, end = rule
        ranges = owner.get("articulation", {}).get(key) or []
        if not ranges:
            raise self.fail(term, f"{name!r} has no {key} in LIBERO's articulation properties")
        return _Joints(tuple(self.joint_qpos(term, j) for j in f.get("joints", [])), op, float(end(ranges)),
                       JOINT_PREDICATES[pred])

    def joint_qpos(self, term: list, joint: str) -> int:
        jid = self.index(term, "joint", joint)
        if int(self.mjm.jnt_type[jid]) not in (2, 3):  # slide, hinge: one qpos each
            raise self.fail(term, f"joint {joint!r} is not a hinge or slide (LIBERO compares one qpos)")
        return int(self.mjm.jnt_qposadr[jid])

    def table(self) -> np.ndarray:
        """bool[ngeom, 2, T]: geom g is in set 0 / 1 of contact test t."""
        out = np.zeros((self.mjm.ngeom, 2, len(self.tests)), bool)
        for t, (a, b) in enumerate(self.tests):
            out[list(a), 0, t] = True
            out[list(b), 1, t] = True
        return out


@dataclass
class GoalCheck:
    """A task's goal compiled for its model: ``met(state)`` and ``values(state)`` (see the module doc)."""

    task: str
    names: tuple[str, ...]
    terms: tuple[Any, ...]
    member: np.ndarray  # bool[ngeom, 2, T] (host); its copy on each array module in ``_tables``
    _tables: dict

    @classmethod
    def compile(cls, task: str, goal_state: list, mjm: Any, objects: dict[str, dict[str, Any]]) -> "GoalCheck":
        if not goal_state:
            raise ConfigError(f"{task}: the goal is empty (LIBERO's goal_state has no predicate)")
        b = _Builder(task, mjm, objects)
        terms = tuple(b.term([str(a) for a in g]) for g in goal_state)
        return cls(task, tuple(shown(g) for g in goal_state), terms, b.table(), {})

    def met(self, state: Any) -> Any:
        """bool[N]: every predicate of the goal holds (LIBERO's ``_check_success``)."""
        return self.values(state).all(axis=1)

    def values(self, state: Any) -> Any:
        """bool[N, P]: each predicate's truth per world, in goal order (``names``)."""
        touch = self.touch(state)
        return state.xp.stack([t(state, touch) for t in self.terms], axis=1)

    def touch(self, state: Any) -> Any:
        """bool[N, T]: each contact test per world."""
        xp, n, tests = state.xp, state.num_worlds, self.member.shape[2]
        if tests == 0:
            return xp.zeros((n, 0), dtype=bool)
        key = xp.__name__
        if key not in self._tables:
            self._tables[key] = xp.asarray(self.member)
        m, g = self._tables[key], state.contact_geom
        a1, b1, a2, b2 = m[g[:, 0], 0], m[g[:, 0], 1], m[g[:, 1], 0], m[g[:, 1], 1]
        hit = ((a1 & b2) | (b1 & a2)).astype(xp.float64)  # [C, T]
        slot = state.contact_world[:, None] * tests + xp.arange(tests)[None, :]
        count = xp.bincount(slot.ravel(), weights=hit.ravel(), minlength=(n + 1) * tests)
        return count[:(n + 1) * tests].reshape(n + 1, tests)[:n] > 0
