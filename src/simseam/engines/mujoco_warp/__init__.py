"""MuJoCo Warp's engine side: the kernels a batched scene runs per world (``kernels``), the CUDA graphs its
steps replay (``graphs``) and a renderer of posed worlds (``pose_renderer``). The batched manifest scene built on them is ``simseam.scene.warp``.
Needs the ``warp`` extra: ``mujoco-warp`` and ``warp-lang``.
"""
