"""MuJoCo Warp's engine side: the kernels a batched scene runs per world (``kernels``), the CUDA graphs its
steps replay (``graphs``), a renderer of posed worlds (``pose_renderer``), and N worlds put on a device or the
one-line error naming the largest N that fits there (``memory``). The batched manifest scene built on them is ``simseam.scene.warp``.
Needs the ``warp`` extra: ``mujoco-warp`` and ``warp-lang``.
"""
