"""LIBERO's scripted pick-and-place expert (``--policy scripted`` on ``libero_spatial`` / ``libero_object``).

LIBERO ships no expert (its demonstrations are human teleoperation). This one reads privileged poses
and the task's goal, never the simulator, so any implementation of LIBERO's scenes (the CPU backend,
a batched GPU port) can drive it:

- the goal: one BDDL predicate ``(On OBJ TARGET)`` or ``(In OBJ REGION)`` from LIBERO's own parsed
  problem (``goal_of``); anything else is a ``ConfigError`` naming the task and the predicate;
- static facts (``Facts``, once per scene): the object's and the target's boxes in their body frames
  (their collision geometry's bounds), the target region's half-sizes (``In``), the gripper's closing
  axis in the end-effector frame and the controller's metres / radians per action unit;
- per step (``Poses``): the end-effector site's position and rotation, the finger opening, the
  object's and the target's world poses and the world boxes of the other bodies' collision geoms.

It is a state machine over ``PHASES``: hover over the grasp point (turned so the fingers close across
the object's narrow side), descend, close, lift (back to the hover when the object did not come up),
carry at a height that clears the target, lower the object onto it (``On``: its bottom just above the
target's top, its centre over the target's; ``In``: inside the region, below the container's rim),
open and retreat. A grasp is a centre grasp when the object fits between the fingers (off centre,
nearer the robot, on a long box), else a rim grasp (LIBERO's bowls) on the side where the outer finger
has room, facing the gripper's start, with the least wrist turn, and not where a grasp failed. Actions
are LIBERO's 7-D OSC_POSE deltas (``[dx, dy, dz, dax, day, daz, grip]`` in [-1, 1], world frame, grip
-1 open / +1 closed), a proportional step towards each phase's target with a speed cap. Deterministic:
the action depends on the poses and the expert's state (phase, grasp, failed sides) alone.

Imports numpy and simseam.seam only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simseam.seam.errors import ConfigError

PREDICATES = ("on", "in")  # the goal predicates the expert handles
PHASES = ("hover", "descend", "close", "lift", "carry", "lower", "release", "retreat")
MAX_OPENING = 0.07  # m: objects narrower than this are grasped across their centre, wider ones by the rim
RIM_INSET = 0.012  # m: rim grasp point inside the rim's outer edge
RIM_DEPTH = 0.02  # m: rim grasp below the rim's top
RIM_SIDES = 16  # rim points considered, evenly around the rim
FINGER_REACH = 0.04  # m from the grasp point to the outer finger (half the fingers' opening)
FINGER_BELOW = 0.03  # m: objects whose top is higher than the grasp point less this are in the fingers' way
ROOM = 0.04  # m of room for the outer finger that counts (more is no better)
FACING = 0.02  # score (m) for a side facing the gripper's start (cosine-weighted)
TURNING = 0.005  # score (m) taken from a side that needs a quarter turn of the wrist (linear in the turn)
FAILED = 0.1  # score (m) taken from a side where a grasp failed
ELONGATED = 1.5  # a box whose long side is this many times its short side is grasped off centre ...
NEAR_SHIFT = 0.02  # m ... this much towards the gripper's start, along the long side
GRASP_DEPTH = 0.03  # m: centre grasp below the object's top (at most half its height)
HOVER = 0.10  # m above the grasp point before descending
CLEARANCE = 0.08  # m: the carried object's bottom above the higher of its start and the target's top
PLACE_GAP = 0.015  # m: On: the object's bottom above the target's top when released
RIM_DROP = 0.05  # m: In: the object's bottom below the container's top when released (kept inside the region)
CLOSE_STEPS = 10
RELEASE_STEPS = 8
MAX_TRIES = 3  # grasps before giving up (the expert then hovers where it is)
TIMEOUT = {"hover": 60, "descend": 40, "lift": 40, "carry": 60, "lower": 40}
SPEED = {"hover": 1.0, "descend": 0.5, "close": 0.5, "lift": 0.8, "carry": 0.8, "lower": 0.4, "release": 0.5,
         "retreat": 0.8}  # cap on the translation action's norm, per phase
POS_TOL = {"hover": 0.01, "descend": 0.006, "lift": 0.02, "carry": 0.01, "lower": 0.008}
ROT_TOL = 0.05  # rad, at the hover
VERTICAL = ("lower",)  # phases that move straight down (the descent to a grasp moves as it goes)
VERTICAL_TOL = 0.008  # m: they stop going down while further than this off the vertical
STILL = 0.003  # m per step: the end-effector has stopped (a phase that ends on arrival waits for it)


@dataclass(frozen=True)
class Goal:
    predicate: str  # "on" | "in"
    obj: str  # the object to move (a movable object's name)
    target: str  # the object it goes on, or the region it goes in
    holder: str  # the body the target belongs to (the target itself for On, the region's parent for In)


@dataclass(frozen=True)
class Facts:
    obj_box: tuple[np.ndarray, np.ndarray]  # (lo, hi) of the object's collision geometry, its body frame
    holder_box: tuple[np.ndarray, np.ndarray]  # the same for the target's body
    region_half: np.ndarray | None  # In: the region's half-sizes (its site frame); None for On
    closing_axis: np.ndarray  # unit vector the fingers close along, in the end-effector frame
    max_translation: float  # m per action unit
    max_rotation: float  # rad per action unit


@dataclass(frozen=True)
class Poses:
    eef_pos: np.ndarray  # (3,) the end-effector (grip) site
    eef_rot: np.ndarray  # (3, 3)
    opening: float  # m between the fingers
    obj_pos: np.ndarray
    obj_rot: np.ndarray
    holder_pos: np.ndarray
    holder_rot: np.ndarray
    region_pos: np.ndarray | None  # In: the region site's position
    region_rot: np.ndarray | None
    obstacles: np.ndarray | tuple = ()  # (K, 2, 3): world (lo, hi) boxes of the other objects' and fixtures'
    # collision geoms (a drawer's walls, not the whole cabinet)


def goal_of(task: str, goal_state: list, movable: set[str], regions: dict[str, str]) -> Goal:
    """The expert's goal from LIBERO's parsed BDDL goal (``parsed_problem["goal_state"]``, e.g.
    ``[["on", "akita_black_bowl_1", "plate_1"]]``); ``movable``: the problem's objects; ``regions``: its
    region sites and their parents. A goal it cannot do is a ``ConfigError`` naming the task: another
    predicate, several predicates, or a target that is a fixture or a fixture's region (a drawer, a
    stove: those goals need more than pick and place, e.g. opening the drawer first)."""
    shown = " ".join("(" + " ".join(str(a) for a in g) + ")" for g in goal_state)
    if len(goal_state) != 1:
        raise ConfigError(f"{task}: the LIBERO expert handles one (On OBJ TARGET) or (In OBJ REGION) goal; "
                          f"this task's goal is {shown}")
    pred, *args = [str(a) for a in goal_state[0]]
    pred = pred.lower()
    if pred not in PREDICATES or len(args) != 2:
        raise ConfigError(f"{task}: the LIBERO expert does not handle the goal predicate {shown} "
                          f"(it handles {', '.join(p.capitalize() for p in PREDICATES)})")
    obj, target = args
    if obj not in movable:
        raise ConfigError(f"{task}: the goal {shown} moves {obj!r}, which is not a movable object")
    if pred == "on" and target in movable:
        return Goal(pred, obj, target, target)
    if pred == "in" and regions.get(target) in movable:
        return Goal(pred, obj, target, regions[target])
    raise ConfigError(f"{task}: the LIBERO expert does not handle the goal {shown} ({target!r} is not "
                      f"{'a movable object' if pred == 'on' else 'a region of a movable object'})")


def world_box(box: tuple[np.ndarray, np.ndarray], pos: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-axis bounds of a body-frame box at a pose."""
    lo, hi = box
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = corners @ rot.T + pos
    return w.min(axis=0), w.max(axis=0)


def rotation_vector(rot: np.ndarray) -> np.ndarray:
    """Axis-angle (3) of a rotation matrix."""
    cos = min(1.0, max(-1.0, (np.trace(rot) - 1.0) / 2.0))
    angle = math.acos(cos)
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    if angle > math.pi - 1e-6:  # near pi: the axis from the symmetric part
        axis = np.sqrt(np.clip((np.diag(rot) + 1.0) / 2.0, 0.0, None))
        return axis / np.linalg.norm(axis) * angle
    return axis / (2.0 * math.sin(angle)) * angle


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class PickPlaceExpert:
    """The expert for one scene: ``reset()`` at each episode, ``act(poses)`` once per observation."""

    def __init__(self, goal: Goal, facts: Facts):
        self.goal, self.facts = goal, facts
        self.reset()

    def reset(self) -> None:
        self.phase, self.t, self.tries = "hover", 0, 0
        self._down: np.ndarray | None = None  # the end-effector rotation at the episode's start
        self._start_xy: np.ndarray | None = None
        self._grasp: tuple[np.ndarray, float] | None = None  # (point, yaw) fixed at the descent
        self._failed: list[np.ndarray] = []  # horizontal closing directions of grasps that failed
        self._obj_bottom0 = 0.0
        self._retreat_from: np.ndarray | None = None
        self._speed = 0.0  # m the end-effector moved since the last observation
        self._last: np.ndarray | None = None

    # ------------------------------------------------------------ geometry
    def _grasp_plan(self, p: Poses) -> tuple[np.ndarray, float]:
        """(grasp point of the end-effector site, the yaw to turn the gripper by from its start)."""
        lo, hi = world_box(self.facts.obj_box, p.obj_pos, p.obj_rot)
        center = p.obj_rot @ ((self.facts.obj_box[0] + self.facts.obj_box[1]) / 2.0) + p.obj_pos
        half = (self.facts.obj_box[1] - self.facts.obj_box[0]) / 2.0
        flat = np.argsort(np.abs(p.obj_rot[2, :]))[:2]  # the body axes closest to horizontal
        narrow = flat[np.argmin(half[flat])]
        height = hi[2] - lo[2]
        if 2.0 * half[narrow] <= MAX_OPENING:
            across = p.obj_rot[:, narrow]
            point = np.array([center[0], center[1], hi[2] - min(GRASP_DEPTH, height / 2.0)])
            wide = flat[flat != narrow][0]
            if half[wide] > ELONGATED * half[narrow]:  # a long box: held nearer the robot (LIBERO's far objects
                along = p.obj_rot[:, wide] * np.sign(p.obj_rot[:, wide][:2] @ (self._start_xy - center[:2]))
                point += min(NEAR_SHIFT, half[wide] - NEAR_SHIFT) * along  # are at the edge of the arm's reach)
        else:  # too wide for the fingers: grasp the rim
            radius = float(np.min(half[flat]))
            z = hi[2] - min(RIM_DEPTH, height / 2.0)
            across = self._rim_side(p, center[:2], radius, z)
            point = np.append(center[:2] + (radius - RIM_INSET) * across[:2], z)
        return point, self._yaw_to(across)

    def _yaw_to(self, across: np.ndarray) -> float:
        """The turn about z (rad) from the start that makes the fingers close along ``across`` (the nearer
        half-turn: the fingers are symmetric)."""
        closing = self._down @ self.facts.closing_axis
        yaw = math.atan2(across[1], across[0]) - math.atan2(closing[1], closing[0])
        return (yaw + math.pi / 2.0) % math.pi - math.pi / 2.0

    def _rim_side(self, p: Poses, center: np.ndarray, radius: float, z: float) -> np.ndarray:
        """The unit direction (3) from the centre to the rim point grasped: the side whose outer finger has the
        most room from the other bodies' collision geoms reaching above the fingertips (up to ``ROOM``), then the one
        facing the gripper's start and needing the least turn of the wrist (far reaches fail turned); sides
        where a grasp already failed are avoided."""
        start = self._start_xy - center
        start /= max(np.linalg.norm(start), 1e-9)
        best, best_score = None, -np.inf
        boxes = np.asarray(p.obstacles, dtype=np.float64).reshape(-1, 2, 3)
        tall = boxes[boxes[:, 1, 2] > z - FINGER_BELOW]
        for angle in np.linspace(0.0, 2.0 * math.pi, RIM_SIDES, endpoint=False):
            u = np.array([math.cos(angle), math.sin(angle)])
            finger = center + (radius - RIM_INSET + FINGER_REACH) * u
            room = ROOM
            if len(tall):
                gap = np.maximum(0.0, np.maximum(tall[:, 0, :2] - finger, finger - tall[:, 1, :2]))
                room = min(room, float(np.min(np.linalg.norm(gap, axis=1))))
            score = (room + FACING * float(u @ start) - TURNING * abs(self._yaw_to(u)) / (math.pi / 2)
                     - sum(FAILED for f in self._failed if abs(u @ f[:2]) > 0.8))
            if score > best_score:
                best, best_score = u, score
        return np.append(best, 0.0)

    def _obj_bottom(self, p: Poses) -> float:
        return float(world_box(self.facts.obj_box, p.obj_pos, p.obj_rot)[0][2])

    def _place_xy(self, p: Poses) -> np.ndarray:
        if self.goal.predicate == "in":
            return p.region_pos[:2]
        lo, hi = self.facts.holder_box
        return (p.holder_rot @ ((lo + hi) / 2.0) + p.holder_pos)[:2]

    def _holder_top(self, p: Poses) -> float:
        return float(world_box(self.facts.holder_box, p.holder_pos, p.holder_rot)[1][2])

    def _release_bottom(self, p: Poses) -> float:
        """Where the object's bottom is when the gripper opens."""
        top = self._holder_top(p)
        if self.goal.predicate == "on":
            return top + PLACE_GAP
        region_floor = p.region_pos[2] - self.facts.region_half[2]
        return max(top - RIM_DROP, region_floor + 0.01)

    # ------------------------------------------------------------- control
    def _move(self, p: Poses, target: np.ndarray, rot: np.ndarray, grip: float) -> np.ndarray:
        ft = self.facts
        d = (target - p.eef_pos) / ft.max_translation
        cap = SPEED[self.phase]
        if self.phase in VERTICAL:  # straight down: the horizontal error is corrected first, the descent capped
            d[:2] = np.clip(d[:2], -1.0, 1.0)
            off = np.linalg.norm(target[:2] - p.eef_pos[:2]) > VERTICAL_TOL
            d[2] = 0.0 if off else np.clip(d[2], -cap, cap)
        elif np.linalg.norm(d) > cap:
            d *= cap / np.linalg.norm(d)
        r = np.clip(rotation_vector(rot @ p.eef_rot.T) / ft.max_rotation, -1.0, 1.0)
        return np.concatenate([d, r, [grip]]).astype(np.float32)

    def _next(self, phase: str) -> None:
        self.phase, self.t = phase, 0

    def act(self, p: Poses) -> np.ndarray:
        if self._down is None:
            self._down, self._start_xy = p.eef_rot.copy(), p.eef_pos[:2].copy()
        self._speed = 0.0 if self._last is None else float(np.linalg.norm(p.eef_pos - self._last))
        self._last = p.eef_pos.copy()
        self.t += 1
        return getattr(self, "_" + self.phase)(p)

    def _reached(self, p: Poses, target: np.ndarray) -> bool:
        near = np.linalg.norm(target - p.eef_pos) < POS_TOL[self.phase] and self._speed < STILL
        return bool(near) or self.t >= TIMEOUT[self.phase]

    def _hover(self, p: Poses) -> np.ndarray:
        point, yaw = self._grasp_plan(p)
        rot = rot_z(yaw) @ self._down
        target = point + [0.0, 0.0, HOVER]
        aligned = np.linalg.norm(rotation_vector(rot @ p.eef_rot.T)) < ROT_TOL
        if (self._reached(p, target) and aligned) or self.t >= TIMEOUT["hover"]:
            self._grasp = (point, yaw)
            self._obj_bottom0 = self._obj_bottom(p)
            self._next("descend")
        return self._move(p, target, rot, -1.0)

    def _descend(self, p: Poses) -> np.ndarray:
        point, yaw = self._grasp
        if self._reached(p, point):
            self._next("close")
        return self._move(p, point, rot_z(yaw) @ self._down, -1.0)

    def _close(self, p: Poses) -> np.ndarray:
        point, yaw = self._grasp
        if self.t >= CLOSE_STEPS:
            self._next("lift")
        return self._move(p, point, rot_z(yaw) @ self._down, 1.0)

    def _carry_z(self, p: Poses) -> float:
        clear = max(self._obj_bottom0, self._holder_top(p)) + CLEARANCE
        return clear + (p.eef_pos[2] - self._obj_bottom(p))

    def _lift(self, p: Poses) -> np.ndarray:
        point, yaw = self._grasp
        target = np.array([point[0], point[1], self._carry_z(p)])
        if self._reached(p, target):
            if self._obj_bottom(p) - self._obj_bottom0 < 0.5 * CLEARANCE:  # the object stayed behind
                self.tries += 1
                self._failed.append(rot_z(yaw) @ self._down @ self.facts.closing_axis)
                self._next("hover" if self.tries < MAX_TRIES else "retreat")
            else:
                self._next("carry")
        return self._move(p, target, rot_z(yaw) @ self._down, 1.0)

    def _carry_target(self, p: Poses, z: float) -> np.ndarray:
        """The end-effector position that puts the object's centre over the place point at height ``z``."""
        lo, hi = self.facts.obj_box
        center = p.obj_rot @ ((lo + hi) / 2.0) + p.obj_pos
        return np.append(self._place_xy(p) + (p.eef_pos[:2] - center[:2]), z)

    def _carry(self, p: Poses) -> np.ndarray:
        target = self._carry_target(p, self._carry_z(p))
        if self._reached(p, target):
            self._next("lower")
        return self._move(p, target, rot_z(self._grasp[1]) @ self._down, 1.0)

    def _lower(self, p: Poses) -> np.ndarray:
        z = self._release_bottom(p) + (p.eef_pos[2] - self._obj_bottom(p))
        target = self._carry_target(p, z)
        if self._reached(p, target):
            self._next("release")
        return self._move(p, target, rot_z(self._grasp[1]) @ self._down, 1.0)

    def _release(self, p: Poses) -> np.ndarray:
        if self.t >= RELEASE_STEPS:
            self._next("retreat")
            self._retreat_from = p.eef_pos.copy()
        return self._move(p, p.eef_pos, p.eef_rot, -1.0)

    def _retreat(self, p: Poses) -> np.ndarray:
        if self._retreat_from is None:  # gave up grasping: straight up from here
            self._retreat_from = p.eef_pos.copy()
        target = self._retreat_from + [0.0, 0.0, HOVER]
        return self._move(p, target, p.eef_rot, -1.0)
