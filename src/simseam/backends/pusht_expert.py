"""PushT's scripted expert: push primitives chosen by simulating each on a twin of the pymunk world.

gym-pusht ships no expert (its dataset is human teleoperation). This one reads the simulator's
privileged state (the agent's and the T's poses and velocities), as ManiSkill's motion planner reads
its scene. A *push* is: reach a point just outside the T's outline (beside one of its edges), then
move the agent's target through the T along the edge's inward normal, turned by each of ``TURNS``,
for one of ``LENGTHS`` px. Every candidate (contact points every ~``EDGE_SPACING`` px along the
outline) is first pushed with the agent placed at its start, on a twin world (gym-pusht's own walls,
agent and T, ``_Twin``) with the env's PD control and 10 physics substeps per step; its cost is the
mean distance of the T's 8 keypoints to the goal's, plus ``TRAVEL_COST`` per px to the push's start
(less near the goal). The ``RERANK`` best are then replayed in full (reach and push) from the live
state, and the best is executed; then the next push is planned from where the world is. Below
``FINE`` px of cost the pushes are short and slow (``FINE_*``), and pushes straight through the
centre of gravity towards the goal's join them. When no push lowers the cost by ``IMPROVE``, the
one after which the best next push is best is taken (one push of look-ahead). Targets move at most
``REACH_SPEED`` px per step while reaching; the reach goes around the T (on a circle about its
centre of gravity) when the straight way would touch it.

Deterministic: the plan depends on the world's state alone. Imports numpy at module level; gym_pusht,
pymunk and shapely only in ``PushTExpert``.
"""

from __future__ import annotations

import math

import numpy as np

GOAL = (256.0, 256.0, math.pi / 4)  # gym-pusht's goal pose (x, y, angle) of the T's body origin
AGENT_RADIUS = 15.0
LENGTHS = (4, 8, 16, 32, 56, 80)  # push lengths (px) whose outcome is evaluated
PUSH_SPEED = 8.0  # px per step while pushing
FINE = 8.0  # below this cost (px) the pushes are short and slow: FINE_LENGTHS at FINE_SPEED, FINE_SETTLE
FINE_LENGTHS = (2, 4, 6, 8, 12, 16, 24)
FINE_SPEED = 2.0
FINE_SETTLE = 3  # steps at a push's start before it (1 otherwise): the PD-driven agent lags its target
REACH_SPEED = 25.0  # px per step while reaching the start of a push
TURNS = (-math.pi / 6, 0.0, math.pi / 6)
FINE_TURNS = tuple(math.radians(a) for a in (-45, -30, -15, 0, 15, 30, 45))
EDGE_SPACING = 15.0
TRAVEL_COST = 0.02
RERANK = 8  # candidates executed in full on the twin
IMPROVE = 0.1  # px of cost a push must remove, else the look-ahead chooses
WALLS = (((5, 506), (5, 5)), ((5, 5), (506, 5)), ((506, 5), (506, 506)), ((5, 506), (506, 506)))
LOW, HIGH = 20.0, 492.0  # targets stay inside the walls (at 5 and 506) by more than the agent's radius
# the T's outline in its body frame (gym-pusht's add_tee, scale 30, length 4), counter-clockwise
OUTLINE = ((-60.0, 0.0), (60.0, 0.0), (60.0, 30.0), (15.0, 30.0), (15.0, 120.0), (-15.0, 120.0), (-15.0, 30.0),
           (-60.0, 30.0))


def keypoints(x: float, y: float, angle: float, local: np.ndarray) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return local @ np.array([[c, s], [-s, c]]) + (x, y)


def contacts() -> list[tuple[np.ndarray, np.ndarray]]:
    """(point, outward normal) in the T's body frame, every ~EDGE_SPACING px along each edge."""
    pts = np.array(OUTLINE)
    area2 = sum(pts[i - 1][0] * pts[i][1] - pts[i][0] * pts[i - 1][1] for i in range(len(pts)))
    out = []
    for i in range(len(pts)):
        a, b = pts[i], pts[(i + 1) % len(pts)]
        edge = b - a
        n = int(max(1, round(np.linalg.norm(edge) / EDGE_SPACING)))
        normal = np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)
        if area2 < 0:
            normal = -normal
        out += [(a + edge * (k + 0.5) / n, normal) for k in range(n)]
    return out


class _Twin:
    """gym-pusht's world (its ``_setup``: walls, agent, T, no gravity, damping 0) without the contact-counting
    callback, which costs as much as the physics."""

    def __init__(self, env_cls):
        import pymunk

        self.space = pymunk.Space()
        self.space.gravity = 0, 0
        self.space.damping = 0.0
        self.space.add(*[env_cls.add_segment(self.space, a, b, 2) for a, b in WALLS])
        self.agent = env_cls.add_circle(self.space, (256, 400), AGENT_RADIUS)
        self.block, _ = env_cls.add_tee(self.space, (256, 300), 0)
        self.k_p, self.k_v, self.dt = 100, 20, 0.01  # PushTEnv's PD gains and physics step


def snapshot(agent, block) -> tuple:
    """The world's moving state: agent position and velocity, the T's position, angle, velocity, spin."""
    return (tuple(agent.position), tuple(agent.velocity), tuple(block.position), float(block.angle),
            tuple(block.velocity), float(block.angular_velocity))


class PushTExpert:
    """``action(env)``: the next target position for the live ``PushTEnv`` ``env``."""

    def __init__(self):
        from gym_pusht.envs import PushTEnv
        import shapely.geometry as sg

        self._sg = sg
        self.twin = _Twin(PushTEnv)
        self._local = np.array([np.array(v) for s in self.twin.block.shapes for v in s.get_vertices()])
        self._goal_kp = keypoints(*GOAL, self._local)
        self._contacts = contacts()
        self._cog = np.array(self.twin.block.center_of_gravity)
        self.reset()

    def reset(self) -> None:
        self._queue: list[np.ndarray] = []

    # ------------------------------------------------------------- the twin
    def cost(self, state: tuple) -> float:
        """Mean distance (px) of the T's 8 keypoints to the goal's."""
        (x, y), angle = state[2], state[3]
        return float(np.linalg.norm(keypoints(x, y, angle, self._local) - self._goal_kp, axis=1).mean())

    def _load(self, state: tuple, agent_at=None) -> None:
        t = self.twin
        t.block.angle = state[3]  # angle first: setting it turns the T about its centre of gravity
        t.block.position = state[2]
        t.block.velocity = state[4]
        t.block.angular_velocity = state[5]
        t.agent.position = tuple(agent_at) if agent_at is not None else state[0]
        t.agent.velocity = (0.0, 0.0) if agent_at is not None else state[1]

    def _step_twin(self, target: np.ndarray) -> None:
        t = self.twin
        agent, space, kp, kv, dt = t.agent, t.space, t.k_p, t.k_v, t.dt
        tx, ty = float(target[0]), float(target[1])
        for _ in range(10):  # gym-pusht's step: PD control of the agent, 10 substeps of 0.01 s
            (px, py), (vx, vy) = agent.position, agent.velocity
            agent.velocity = (vx + (kp * (tx - px) - kv * vx) * dt, vy + (kp * (ty - py) - kv * vy) * dt)
            space.step(dt)

    def _replay(self, state: tuple, targets: list[np.ndarray]) -> tuple:
        """The state after executing ``targets`` from ``state`` on the twin."""
        self._load(state)
        for t in targets:
            self._step_twin(t)
        return snapshot(self.twin.agent, self.twin.block)

    # ------------------------------------------------------------ pushes
    def _candidates(self, state: tuple, fine: bool):
        """(start, direction) of each push: beside every contact point, along its inward normal turned by each
        of TURNS (FINE_TURNS when fine); when fine also straight through the centre of gravity towards the goal's."""
        (x, y), ang = state[2], state[3]
        c, s = math.cos(ang), math.sin(ang)
        rot = np.array([[c, -s], [s, c]])
        if fine:
            yield from self._through_centre(rot, np.array([x, y]))
        for p, n in self._contacts:
            wp, wn = rot @ p + (x, y), rot @ n
            start = wp + wn * (AGENT_RADIUS + 2.0)
            if not (LOW <= start[0] <= HIGH and LOW <= start[1] <= HIGH):
                continue
            for turn in FINE_TURNS if fine else TURNS:
                ct, st = math.cos(turn), math.sin(turn)
                yield start, -np.array([ct * wn[0] - st * wn[1], st * wn[0] + ct * wn[1]])

    def _through_centre(self, rot: np.ndarray, pos: np.ndarray):
        """Pushes that translate the T towards the goal: along the line from its centre of gravity to the goal's,
        from where that line leaves the T's outline behind it."""
        sg = self._sg
        cog = rot @ self._cog + pos
        gc, gs = math.cos(GOAL[2]), math.sin(GOAL[2])
        goal_cog = np.array([[gc, -gs], [gs, gc]]) @ self._cog + GOAL[:2]
        gap = goal_cog - cog
        if np.linalg.norm(gap) < 1e-3:
            return
        u = gap / np.linalg.norm(gap)
        outline = sg.Polygon([tuple(rot @ v + pos) for v in OUTLINE]).exterior
        hit = outline.intersection(sg.LineString([cog, cog - u * 200.0]))
        pts = [np.array(g.coords[0]) for g in getattr(hit, "geoms", [hit]) if not g.is_empty]
        if pts:
            back = max(pts, key=lambda p: float(np.dot(cog - p, cog - p)))
            yield back - u * (AGENT_RADIUS + 2.0), u

    def _simulate(self, state: tuple, start: np.ndarray, d: np.ndarray, fine: bool) -> list[float]:
        """The cost after each push length, the agent placed at ``start`` and pushing along ``d``."""
        self._load(state, agent_at=start)
        out, pushed, speed = [], 0.0, FINE_SPEED if fine else PUSH_SPEED
        for length in FINE_LENGTHS if fine else LENGTHS:
            while pushed < length - 1e-9:
                pushed = min(length, pushed + speed)
                self._step_twin(np.clip(start + d * pushed, LOW, HIGH))
            out.append(self.cost(snapshot(self.twin.agent, self.twin.block)))
        return out

    def _reach(self, state: tuple, start: np.ndarray, fine: bool) -> list[np.ndarray]:
        """Targets from the agent to ``start`` (around the T when the straight way would touch it)."""
        (x, y), ang = state[2], state[3]
        agent = np.array(state[0])
        c, s = math.cos(ang), math.sin(ang)
        sg = self._sg
        block = sg.Polygon([(c * u - s * v + x, s * u + c * v + y) for u, v in OUTLINE])
        path = [agent]
        if block.distance(sg.LineString([agent, start])) < AGENT_RADIUS + 2.0:
            cog = np.array([c * self._cog[0] - s * self._cog[1] + x, s * self._cog[0] + c * self._cog[1] + y])
            radius = 76.5 + AGENT_RADIUS + 10.0  # the T's farthest point from its centre of gravity + margin
            a0 = math.atan2(agent[1] - cog[1], agent[0] - cog[0])
            turn = (math.atan2(start[1] - cog[1], start[0] - cog[0]) - a0 + math.pi) % (2 * math.pi) - math.pi
            n = max(2, int(abs(turn) * radius / REACH_SPEED) + 1)
            path += [cog + radius * np.array([math.cos(a0 + turn * k / n), math.sin(a0 + turn * k / n)])
                     for k in range(n + 1)]
        path.append(start)
        targets = []
        for a, b in zip(path[:-1], path[1:]):
            n = max(1, int(math.ceil(np.linalg.norm(b - a) / REACH_SPEED)))
            targets += [a + (b - a) * (k / n) for k in range(1, n + 1)]
        targets += [start] * (FINE_SETTLE if fine else 1)  # settle at the start
        return [np.clip(t, LOW, HIGH) for t in targets]

    def _push(self, start: np.ndarray, d: np.ndarray, length: float, fine: bool) -> list[np.ndarray]:
        speed = FINE_SPEED if fine else PUSH_SPEED
        n = int(math.ceil(length / speed))
        return [np.clip(start + d * min(length, speed * k), LOW, HIGH) for k in range(1, n + 1)]

    @staticmethod
    def _travel_weight(cost: float) -> float:
        """TRAVEL_COST per px travelled, less near the goal where a push gains fractions of a px."""
        return TRAVEL_COST * min(1.0, cost / 20.0)

    def _ranked(self, state: tuple, fine: bool) -> list[tuple]:
        """Every (score, index, start, direction, length), best first: each candidate pushed from its start."""
        agent = np.array(state[0])
        now = self.cost(state)
        weight = self._travel_weight(now)
        ranked = []
        for start, d in self._candidates(state, fine):
            travel = float(np.linalg.norm(start - agent)) * weight
            for cost, length in zip(self._simulate(state, start, d, fine), FINE_LENGTHS if fine else LENGTHS):
                if cost < now - IMPROVE / 10:  # pushes that do not move the T are no candidates
                    ranked.append((cost + travel, len(ranked), start, d, length))
        ranked.sort(key=lambda r: (r[0], r[1]))
        return ranked

    def plan(self, state: tuple) -> list[np.ndarray]:
        """The targets of the best push from ``state``: every candidate pushed from its start (the agent placed
        there), then the ``RERANK`` best executed in full (reach and push) from ``state``. When none lowers the
        cost by ``IMPROVE``, the one whose end state offers the best next push (a look-ahead of one push)."""
        now = self.cost(state)
        fine = now < FINE
        ranked = self._ranked(state, fine)
        if not ranked:  # the T against a wall on every side: move to the centre
            return [np.array([256.0, 256.0])]
        plans = [self._reach(state, start, fine) + self._push(start, d, length, fine)
                 for _, _, start, d, length in ranked[:RERANK]]
        ends = [self._replay(state, p) for p in plans]
        costs = [self.cost(e) for e in ends]
        scores = [c + self._travel_weight(now) * REACH_SPEED * len(p) for c, p in zip(costs, plans)]
        best = int(np.argmin(scores))
        if costs[best] < now - IMPROVE:
            return plans[best]
        # no push helps at once: the one (that moves the T) after which the best next push is best
        ahead = [min((r[0] for r in self._ranked(e, self.cost(e) < FINE)[:1]), default=math.inf)
                 if abs(c - now) > 0.01 else math.inf for e, c in zip(ends, costs)]
        return plans[int(np.argmin(ahead))]

    def action(self, env) -> np.ndarray:
        if not self._queue:
            self._queue = self.plan(snapshot(env.agent, env.block))
        return np.asarray(self._queue.pop(0), dtype=np.float32)
