"""`collision: primitives` in a robot manifest: fitted capsules (boxes for the gripper's fingers)
collide in place of the URDF's collision meshes, which keep the links' mass and inertia."""

import dataclasses

import mujoco
import numpy as np

from simseam.policies.base import make_policy
from simseam.robot.manifest import load_robot
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import STATE_ONLY

OPTS = SceneOptions(render_images=False, privileged=True)


def _robot_geoms(scene):
    m = scene.engine.model
    robot = set(scene.engine._body_ids.values())
    return m, [g for g in range(m.ngeom) if m.geom_bodyid[g] in robot]


def test_primitives_replace_mesh_collisions_and_keep_the_mass():
    panda = load_robot("franka_panda")
    mesh = ManifestScene(panda, "lift_cube", "mujoco", OPTS)
    prim = ManifestScene(dataclasses.replace(panda, collision="primitives"), "lift_cube", "mujoco", OPTS)
    m0, g0 = _robot_geoms(mesh)
    m1, g1 = _robot_geoms(prim)
    colliding = lambda m, gs: [g for g in gs if m.geom_contype[g] or m.geom_conaffinity[g]]  # noqa: E731
    assert {int(m0.geom_type[g]) for g in colliding(m0, g0)} == {mujoco.mjtGeom.mjGEOM_MESH}
    kinds = {int(m1.geom_type[g]) for g in colliding(m1, g1)}
    assert kinds == {mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX}
    assert len(colliding(m1, g1)) == len(colliding(m0, g0))
    fingers = {m1.body(n).id for n in ("panda_leftfinger", "panda_rightfinger")}
    for g in colliding(m1, g1):
        is_box = m1.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
        assert is_box == (m1.geom_bodyid[g] in fingers)
        assert m1.geom_size[g][0] > 0.005  # fitted to its mesh, not a degenerate default
    np.testing.assert_allclose(m1.body_mass, m0.body_mass, rtol=1e-9)
    np.testing.assert_allclose(m1.body_inertia, m0.body_inertia, rtol=1e-9)
    # the scripted expert still lifts the cube with the proxies
    pol = make_policy("scripted")
    for seed in (0, 1, 2):
        pol.reset(prim.spec)
        obs = prim.reset(seed, STATE_ONLY)
        for _ in range(prim.spec.task.max_steps):
            r = prim.step(pol.act(obs), STATE_ONLY)
            obs = r.observation
            if r.terminated:
                break
        assert r.info["success"], seed
    mesh.close()
    prim.close()
