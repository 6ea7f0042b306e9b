"""Fast offscreen RGB-D (+ instance segmentation) rendering of one MuJoCo camera.

One ``mjr_render`` and one ``mjr_readPixels`` fill the colour and depth buffers together;
shadows, reflections, skybox and MSAA are off and primitive meshes are coarse, which is
what makes CPU (llvmpipe) rendering reach ~1 ms per 64x64 frame. Depth is linearised
from MuJoCo's reversed-Z buffer with the model's near/far planes and is planar z-depth
along the optical axis (Habitat's convention). Segmentation is a second, flat-colour
render and only happens when asked for.
"""

from __future__ import annotations

import logging
import re

import mujoco
import numpy as np

from vla_gr.geometry.robot_spec import MAX_DEPTH

logger = logging.getLogger(__name__)

_OBJ_NAME = re.compile(r"^obj(\d+)(?:_|$)")


def tune_model_for_speed(model: mujoco.MjModel, width: int, height: int, znear_m: float = 0.05):
    """Set visual options on a compiled ``model`` before any render context is made.

    No MSAA, no shadow map, coarse slices for cylinders/spheres, an offscreen buffer of at
    least ``width`` x ``height`` and a near plane of ``znear_m`` metres.
    """
    quality = model.vis.quality
    quality.offsamples = 0
    quality.shadowsize = 0
    quality.numslices = min(int(quality.numslices), 8)
    quality.numstacks = min(int(quality.numstacks), 4)
    quality.numquads = 1
    glob = model.vis.global_
    glob.offwidth = max(int(glob.offwidth), width)
    glob.offheight = max(int(glob.offheight), height)
    extent = float(model.stat.extent)
    model.vis.map.znear = znear_m / extent


def linearize_depth(buffer: np.ndarray, znear: float, zfar: float) -> np.ndarray:
    """Metric planar depth (H, W) float32 from a reversed-Z depth ``buffer`` (H, W) in [0, 1].

    MuJoCo >= 3.3 renders with reversed Z (1 at the near plane, 0 at the far plane);
    the inverse of its projection is ``d / (b + c)`` with the glFrustum coefficients below,
    computed in float64 as ``mujoco.Renderer`` does.
    """
    zf, zn = np.float32(zfar), np.float32(znear)
    c = -(zf + zn) / (zf - zn)
    d = -(np.float32(2) * zf * zn) / (zf - zn)
    c = np.float64(np.float32(-0.5) * c - np.float32(0.5))
    d = np.float64(np.float32(-0.5) * d)
    return (d / (buffer.astype(np.float64) + c)).astype(np.float32)  # (H, W)


def geom_instance_ids(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) int32: furniture instance id of every geom (from names ``obj{id}_*``), else 0."""
    ids = np.zeros(model.ngeom, dtype=np.int32)
    for g in range(model.ngeom):
        match = _OBJ_NAME.match(model.geom(g).name or "")
        if match is None:
            body_name = model.body(int(model.geom_bodyid[g])).name or ""
            match = _OBJ_NAME.match(body_name)
        if match is not None:
            ids[g] = int(match.group(1))
    return ids


class RGBDRenderer:
    """Renders one fixed camera of ``model`` into RGB uint8 (H, W, 3) and depth float32 (H, W).

    ``gl_context`` is a made-current-on-demand ``mujoco.GLContext`` that may be shared by
    several renderers of one process (one per cached scene). Call ``tune_model_for_speed``
    on the model first.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        gl_context,
        width: int,
        height: int,
        camera_id: int,
        max_depth: float = MAX_DEPTH,
        hidden_groups: tuple[int, ...] = (3,),
    ) -> None:
        if width <= 0 or height <= 0:
            raise ValueError(f"width={width}, height={height} must be positive")
        if not 0 <= camera_id < model.ncam:
            raise ValueError(f"camera_id={camera_id} is not a camera of the model")
        if max_depth <= 0:
            raise ValueError(f"max_depth={max_depth} must be > 0")
        self.model = model
        self.width, self.height, self.max_depth = width, height, max_depth
        self._gl = gl_context
        self._gl.make_current()
        self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=model.ngeom + 16)
        flags = self._scene.flags
        for flag in ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX", "mjRND_FOG", "mjRND_HAZE"):
            flags[getattr(mujoco.mjtRndFlag, flag)] = 0
        self._option = mujoco.MjvOption()
        for group in hidden_groups:
            self._option.geomgroup[group] = 0
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = camera_id
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)  # (H, W, 3) upside down
        self._depth = np.empty((height, width), dtype=np.float32)  # (H, W) upside down
        extent = float(model.stat.extent)
        self.znear = float(model.vis.map.znear) * extent
        self.zfar = float(model.vis.map.zfar) * extent
        self._geom_instance = geom_instance_ids(model)  # (ngeom,)
        self._seg_lut: np.ndarray | None = None  # (ngeom_scene + 1,) segid -> instance id
        self._seg_lut_ngeom = -1

    def render(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and planar depth (H, W) float32 metres in [0, max_depth]."""
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self.model,
            data,
            self._option,
            None,
            self._camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self._scene,
        )
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        mujoco.mjr_render(self._rect, self._scene, self._con)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._con)
        rgb = self._rgb[::-1].copy()  # (H, W, 3) image rows top to bottom
        depth = linearize_depth(self._depth[::-1], self.znear, self.zfar)  # (H, W)
        np.clip(depth, 0.0, self.max_depth, out=depth)
        return rgb, depth

    def render_segmentation(self, data: mujoco.MjData) -> np.ndarray:
        """Instance ids (H, W) int32 of the furniture seen (0 = walls, floor, background).

        Uses the scene built by the last ``render`` call (same robot pose).
        """
        self._gl.make_current()
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
            mujoco.mjr_render(self._rect, self._scene, self._con)
            mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        img = self._rgb[::-1].astype(np.int32)  # (H, W, 3)
        segid = img[..., 0] + (img[..., 1] << 8) + (img[..., 2] << 16)  # (H, W), 0 = none
        lut = self._segmentation_lut()
        segid = np.minimum(segid, lut.shape[0] - 1)
        return lut[segid]  # (H, W) int32

    def _segmentation_lut(self) -> np.ndarray:
        """(ngeom_scene + 1,) int32 map from segmentation colour id to instance id."""
        ngeom = self._scene.ngeom
        if self._seg_lut is None or ngeom != self._seg_lut_ngeom:
            # mjv_updateScene adds geoms in model order for a fixed option, so the map only
            # changes when the number of scene geoms does.
            lut = np.zeros(ngeom + 1, dtype=np.int32)
            geom_type = mujoco.mjtObj.mjOBJ_GEOM
            for i in range(ngeom):
                g = self._scene.geoms[i]
                if g.segid >= 0 and g.objtype == geom_type and 0 <= g.objid < self.model.ngeom:
                    lut[g.segid + 1] = self._geom_instance[g.objid]
            self._seg_lut, self._seg_lut_ngeom = lut, ngeom
        return self._seg_lut

    def close(self) -> None:
        """Free the GPU/GL resources of this renderer (the shared GL context stays)."""
        if self._con is not None:
            try:
                self._gl.make_current()
                self._con.free()
            except Exception:  # noqa: BLE001 - best effort during interpreter shutdown
                logger.debug("MjrContext.free failed", exc_info=True)
            self._con = None


def make_gl_context(width: int, height: int):
    """A headless ``mujoco.GLContext`` (backend from ``MUJOCO_GL``: egl, osmesa or glfw).

    ``vla_gr.envs`` sets ``LP_NUM_THREADS=0`` on import unless the user set it: Mesa's
    llvmpipe (CPU rendering) then rasterises in the calling thread, as fast for small
    frames, and a process that forks after rendering (``AsyncVectorEnv``) does not hang on
    rasteriser threads that do not exist in the child. GPU drivers ignore it.
    """
    return mujoco.GLContext(width, height)
