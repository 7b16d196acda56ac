"""Each Meta-World task's ``_get_pos_objects`` / ``_get_quat_objects`` as data: which element gives the
object positions and orientations in the 39-D observation (read from Meta-World v3's env files).

A position is ``(kind, name, offset)``: kind ``body`` (``get_body_com``: body ``xpos``), ``site`` or ``geom``
(their ``xpos``), or ``dial`` (dial-turn's knob: the dial body's position plus 0.05 m along the knob
joint's angle). A quaternion is ``(kind, name)``: ``body`` (MuJoCo's ``xquat``, wxyz), ``geom_mat`` /
``site_mat`` / ``body_mat`` (``scipy``'s ``Rotation.from_matrix(xmat).as_quat()``: xyzw, scipy's sign
rule), ``identity`` ([1, 0, 0, 0]) or ``zeros``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ObjectSlots:
    pos: tuple[tuple[str, str, tuple[float, float, float]], ...]
    quat: tuple[tuple[str, str], ...]


Z = (0.0, 0.0, 0.0)


def _one(pos_kind: str, pos_name: str, quat_kind: str, quat_name: str = "", offset=Z) -> ObjectSlots:
    return ObjectSlots(((pos_kind, pos_name, tuple(offset)),), ((quat_kind, quat_name),))


OBJECTS: dict[str, ObjectSlots] = {
    "assembly-v3": _one("site", "RoundNut-8", "body", "RoundNut"),
    "basketball-v3": _one("body", "bsktball", "body", "bsktball"),
    "bin-picking-v3": _one("body", "obj", "body", "obj"),
    "box-close-v3": _one("body", "top_link", "body", "top_link"),
    "button-press-topdown-v3": _one("body", "button", "body", "button", (0.0, 0.0, 0.193)),
    "button-press-topdown-wall-v3": _one("body", "button", "body", "button", (0.0, 0.0, 0.193)),
    "button-press-v3": _one("body", "button", "body", "button", (0.0, -0.193, 0.0)),
    "button-press-wall-v3": _one("body", "button", "body", "button", (0.0, -0.193, 0.0)),
    "coffee-button-v3": _one("site", "buttonStart", "identity"),
    "coffee-pull-v3": _one("body", "obj", "geom_mat", "mug"),
    "coffee-push-v3": _one("body", "obj", "geom_mat", "mug"),
    "dial-turn-v3": _one("dial", "dial", "body", "dial"),
    "disassemble-v3": _one("site", "RoundNut-8", "body", "RoundNut"),
    "door-close-v3": _one("geom", "handle", "geom_mat", "handle"),
    "door-lock-v3": _one("site", "lockStartLock", "body", "door_link"),
    "door-unlock-v3": _one("site", "lockStartUnlock", "body", "door_link"),
    "door-open-v3": _one("geom", "handle", "geom_mat", "handle"),
    "drawer-close-v3": _one("body", "drawer_link", "zeros", "", (0.0, -0.16, 0.05)),
    "drawer-open-v3": _one("body", "drawer_link", "body", "drawer_link", (0.0, -0.16, 0.0)),
    "faucet-close-v3": _one("site", "handleStartClose", "body", "faucetBase", (0.0, 0.0, -0.01)),
    "faucet-open-v3": _one("site", "handleStartOpen", "body", "faucetBase", (0.0, 0.0, -0.01)),
    "hammer-v3": ObjectSlots((("body", "hammer", Z), ("body", "nail_link", Z)),
                             (("body", "hammer"), ("body", "nail_link"))),
    "hand-insert-v3": _one("body", "obj", "body", "obj"),
    "handle-press-side-v3": _one("site", "handleStart", "zeros"),
    "handle-press-v3": _one("site", "handleStart", "zeros"),
    "handle-pull-side-v3": _one("site", "handleCenter", "zeros"),
    "handle-pull-v3": _one("site", "handleRight", "zeros"),
    "lever-pull-v3": _one("site", "leverStart", "geom_mat", "objGeom"),
    "peg-insert-side-v3": _one("site", "pegGrasp", "site_mat", "pegGrasp"),
    "peg-unplug-side-v3": _one("site", "pegEnd", "body", "plug1"),
    "pick-out-of-hole-v3": _one("body", "obj", "body", "obj"),
    "pick-place-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "pick-place-wall-v3": _one("geom", "objGeom", "geom_mat", "objGeom"),
    "plate-slide-back-side-v3": _one("geom", "puck", "geom_mat", "puck"),
    "plate-slide-back-v3": _one("geom", "puck", "geom_mat", "puck"),
    "plate-slide-side-v3": _one("geom", "puck", "geom_mat", "puck"),
    "plate-slide-v3": _one("geom", "puck", "geom_mat", "puck"),
    "push-back-v3": _one("geom", "objGeom", "geom_mat", "objGeom"),
    "push-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "push-wall-v3": _one("geom", "objGeom", "geom_mat", "objGeom"),
    "reach-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "reach-wall-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "shelf-place-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "soccer-v3": _one("body", "soccer_ball", "body_mat", "soccer_ball"),
    "stick-pull-v3": ObjectSlots((("body", "stick", Z), ("site", "insertion", Z)),
                                 (("body_mat", "stick"), ("zeros", ""))),
    "stick-push-v3": ObjectSlots((("body", "stick", Z), ("site", "insertion", (0.0, 0.09, 0.0))),
                                 (("body_mat", "stick"), ("zeros", ""))),
    "sweep-into-v3": _one("body", "obj", "geom_mat", "objGeom"),
    "sweep-v3": _one("body", "obj", "body", "obj"),
    "window-close-v3": _one("site", "handleCloseStart", "zeros"),
    "window-open-v3": _one("site", "handleOpenStart", "zeros"),
}

DIAL_RADIUS = 0.05
DIAL_JOINT = "knob_Joint_1"


def scipy_quat(xp, m):
    """float[..., 3, 3] -> xyzw float[..., 4]: scipy's ``Rotation.from_matrix(m).as_quat()`` (the largest of
    the diagonal and the trace picks the branch; no sign rule beyond it), every branch evaluated and the
    right one selected per row."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    dec = xp.stack([m00, m11, m22, tr], axis=-1)
    choice = xp.argmax(dec, axis=-1)
    c = []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        q = [None] * 4
        q[i] = 1.0 - tr + 2.0 * m[..., i, i]
        q[j] = m[..., j, i] + m[..., i, j]
        q[k] = m[..., k, i] + m[..., i, k]
        q[3] = m[..., k, j] - m[..., j, k]
        c.append(xp.stack(q, axis=-1))
    c.append(xp.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1],
                       1.0 + tr], axis=-1))
    q = xp.where((choice == 0)[..., None], c[0], xp.where((choice == 1)[..., None], c[1],
                                                         xp.where((choice == 2)[..., None], c[2], c[3])))
    return q / xp.linalg.norm(q, axis=-1, keepdims=True)
