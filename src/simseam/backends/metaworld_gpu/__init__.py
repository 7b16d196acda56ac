"""Meta-World v3 on MuJoCo Warp: each task's model compiled from Meta-World's own files, resets taken from
the native env, N worlds of one task stepped on the device with Meta-World's control and observation.

``state.py``: ``MetaWorldState``, what the batched reward and success code reads.
"""
