"""The shared arena: a table with its top at z = 0, a light and an outside camera."""

from __future__ import annotations

from dm_control import composer


class Arena(composer.Arena):
    """Table with its top at z = 0, lit for a 64x64 wrist camera; `noslip_iterations` passes of MuJoCo's noslip
    solver after each constraint solve (0: none)."""

    def _build(self, offscreen_size: int, noslip_iterations: int = 0):
        super()._build(name="arena")
        root = self._mjcf_root
        root.option.set_attributes(cone="elliptic", impratio=10, integrator="implicitfast",
                                   noslip_iterations=noslip_iterations)
        root.option.flag.set_attributes(multiccd="enable")
        # An offscreen buffer of the camera's own size, no multisampling and no shadows: 64x64 frames cost a
        # fraction of a millisecond on a software renderer instead of tens.
        root.visual.__getattr__("global").set_attributes(offwidth=offscreen_size, offheight=offscreen_size)
        root.visual.quality.set_attributes(offsamples=0, shadowsize=0, numslices=12, numstacks=4, numquads=1)
        root.visual.map.set_attributes(znear=0.005)
        self._mjcf_root.worldbody.add("light", pos=(0.5, 0, 1.5), dir=(0, 0, -1), castshadow=False)
        self._mjcf_root.worldbody.add("geom", name="table", type="box", size=(0.63, 0.45, 0.02),
                                      pos=(0.5, 0, -0.02), rgba=(0.55, 0.45, 0.35, 1),
                                      contype=1, conaffinity=12)
        self._mjcf_root.worldbody.add("camera", name="outside", pos=(0.5, -0.3, 0.25), xyaxes=(1, 0, 0, 0, 0.55, 0.83),
                                      fovy=45)
