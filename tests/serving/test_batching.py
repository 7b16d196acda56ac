"""serve-policy with several clients at once: per-client episode state, requests batched across clients;
``remote:`` batches (one connection per environment) equal their unbatched selves."""

import threading

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import make_policy_batch
from simseam.serving import PolicyServer

SEEDS = (3, 8, 11)
STEPS = 20


def _local_actions(policy_spec, scene, seed, steps=STEPS, seen=None, **kw):
    """The policy's per-step actions alone on ``scene`` (and, into ``seen``, the observations they answered)."""
    policy = make_policy(policy_spec, **kw)
    policy.reset(scene.spec)
    obs = scene.reset(seed, policy.observe_next())
    out = []
    for _ in range(steps):
        if seen is not None:
            seen.append(obs)
        a = policy.act(obs)
        out.append(a)
        obs = scene.step(a, policy.observe_next()).observation
    return np.stack(out)


@pytest.fixture
def batching_server():
    servers = []

    def _serve(policy_spec, n=3, **kw):
        batch = make_policy_batch(policy_spec, n, **kw)
        rep = batch.policy if hasattr(batch, "policy") else batch.policies[0]
        servers.append(PolicyServer(rep, port=0, verbose=False, batch=batch, max_batch_size=n, max_wait_ms=200.0,
                                    busy_wait=0.2).start())
        return servers[-1]

    yield _serve
    for s in servers:
        s.stop()


def test_three_concurrent_clients_each_keep_their_episode_and_are_batched(batching_server, panda_spec, make_scene):
    server = batching_server("scripted")
    scenes = [make_scene(panda_spec, privileged=True, max_steps=40) for _ in SEEDS]
    reference = [_local_actions("scripted", make_scene(panda_spec, privileged=True, max_steps=40), seed)
                 for seed in SEEDS]
    got, errors = {}, []
    start = threading.Barrier(3)

    def client(k):
        try:
            with make_policy(f"remote:{server.url}") as pol:
                start.wait(timeout=60)
                got[k] = _local_actions_from(pol, scenes[k], SEEDS[k])
        except Exception as exc:  # noqa: BLE001  (re-raised below with the client's number)
            errors.append((k, exc))

    threads = [threading.Thread(target=client, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=240)
    assert not errors, errors
    for k in range(3):
        np.testing.assert_array_equal(got[k], reference[k])  # the scripted expert's phases are per client
    assert server.requests == 3 * STEPS
    assert max(server.batch_sizes) >= 2  # requests of different clients shared a policy call
    assert server.batches < server.requests
    # a fourth client finds every slot taken while three are connected
    from simseam.policies.remote import RemotePolicyError

    held = [make_policy(f"remote:{server.url}") for _ in range(3)]
    try:
        with pytest.raises(RemotePolicyError, match="busy"):
            make_policy(f"remote:{server.url}").act(scenes[0].reset(0))
    finally:
        for p in held:
            p.close()


def _local_actions_from(pol, scene, seed, steps=STEPS):
    pol.reset(scene.spec)
    obs = scene.reset(seed, pol.observe_next())
    out = []
    for _ in range(steps):
        a = pol.act(obs)
        out.append(a)
        obs = scene.step(a, pol.observe_next()).observation
    return np.stack(out)


def _drive_batch(batch, scenes, replay=None):
    """The batch's per-step actions; with ``replay`` (per environment, an unbatched run's observations) it
    answers those instead of its own rollouts' (floats summed in another order then cannot compound
    through the closed loop: only the batching is compared)."""
    obs = []
    for env, (scene, seed) in enumerate(zip(scenes, SEEDS)):
        batch.reset(env, scene.spec)
        obs.append(scene.reset(seed, batch.observe_next(env)))
    out = [[] for _ in scenes]
    for t in range(STEPS):
        if replay is not None:
            obs = [r[t] for r in replay]
        acts = batch.act_batch(list(range(len(scenes))), obs)
        for env, scene in enumerate(scenes):
            out[env].append(acts[env])
            obs[env] = scene.step(acts[env], batch.observe_next(env)).observation
    return [np.stack(a) for a in out]


def test_remote_batch_equals_unbatched_and_sends_one_batch_per_step(batching_server, panda_spec, make_scene):
    server = batching_server("scripted")
    batch = make_policy_batch(f"remote:{server.url}", 3)
    assert type(batch).__name__ == "RemoteBatch" and batch.requires_privileged
    try:
        got = _drive_batch(batch, [make_scene(panda_spec, privileged=True, max_steps=40) for _ in SEEDS])
    finally:
        batch.close()
    for env, seed in enumerate(SEEDS):
        np.testing.assert_array_equal(got[env], _local_actions("scripted", make_scene(panda_spec, privileged=True,
                                                                                      max_steps=40), seed))
    assert server.requests == 3 * STEPS
    assert server.batch_sizes.count(3) >= STEPS // 2  # the three requests of a step mostly form one batch


@pytest.mark.learning
def test_served_lerobot_batches_clients_into_one_forward_pass(batching_server, tiny_act, panda_spec, make_scene):
    out, _ = tiny_act
    server = batching_server(f"lerobot:{out}", device="cpu")
    seen = [[] for _ in SEEDS]
    refs = [_local_actions(f"lerobot:{out}", make_scene(panda_spec, image_size=(40, 56), max_steps=40), seed,
                           seen=seen[env], device="cpu") for env, seed in enumerate(SEEDS)]
    batch = make_policy_batch(f"remote:{server.url}", 3)
    try:
        got = _drive_batch(batch, [make_scene(panda_spec, image_size=(40, 56), max_steps=40) for _ in SEEDS],
                           replay=seen)
    finally:
        batch.close()
    for env, ref in enumerate(refs):
        np.testing.assert_allclose(got[env], ref, rtol=1e-3, atol=2e-4)  # float32 sums in another order
    served = server.batch
    from simseam.policies.lerobot_policy import LeRobotBatch

    assert isinstance(served, LeRobotBatch)
    assert served.forward_passes < served.chunks_predicted  # clients shared forward passes


def test_serve_policy_cli_serves_three_clients_at_once(cli, panda_spec, make_scene):
    """The real `serve-policy` process: three concurrent clients, each its own episode."""
    proc, url = cli("--policy", "scripted", "--max-clients", "3", "--max-wait-ms", "50")
    reference = [_local_actions("scripted", make_scene(panda_spec, privileged=True, max_steps=40), seed)
                 for seed in SEEDS]
    scenes = [make_scene(panda_spec, privileged=True, max_steps=40) for _ in SEEDS]
    got, errors = {}, []
    start = threading.Barrier(3)

    def client(k):
        try:
            with make_policy(f"remote:{url}") as pol:
                assert pol.metadata["max_clients"] == 3
                start.wait(timeout=60)
                got[k] = _local_actions_from(pol, scenes[k], SEEDS[k])
        except Exception as exc:  # noqa: BLE001
            errors.append((k, exc))

    threads = [threading.Thread(target=client, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=240)
    assert not errors, errors
    for k in range(3):
        np.testing.assert_array_equal(got[k], reference[k])
