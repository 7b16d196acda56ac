"""LIBERO on MuJoCo Warp (issue 38, first parts): each task's model compiled by LIBERO / robosuite in the LIBERO
backend's venv and checked here (``model.py``), robosuite's OSC_POSE controller and the Panda gripper's ramp
batched over worlds (``control.py``), the physics terms they read from CPU MuJoCo or MuJoCo Warp
(``physics.py``), and the native worker that records robosuite's own controller (``native.py``, ``worker.py``).
"""
