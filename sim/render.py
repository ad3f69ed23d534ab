"""Off-screen rendering of the onboard camera (RGB + metric depth in one pass, segmentation).

One ``mujoco.mjr_render`` fills the colour and the depth buffer; one
``mujoco.mjr_readPixels`` reads both. The depth buffer is reversed-Z
(``mjDEPTH_ZEROFAR``) and is linearised to planar z-depth in metres exactly as MuJoCo's own
``mujoco.Renderer`` does (``mujoco/rendering/classic/renderer.py``).

The onboard view leaves out the drone's geom group (``sim.names.DRONE_GEOM_GROUP``): a real
camera does not image its own housing. External views (``camera="chase"`` or a
``mujoco.MjvCamera``) show it.

The state is drawn into a scene on the caller's thread (``mjv_updateScene``: it reads the
simulation's data); the scene is rendered and read back on the process's OpenGL thread
(``sim.gl.submit_gl``), which reads nothing but the scene. ``render_async`` returns at once,
so the caller steps the physics and estimates while the image is drawn; two scenes take
turns, so that the next state can be drawn while the last is rendered.
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim import names
from sim.config import RENDER_QUALITY, RenderQuality
from sim.gl import create_gl_context, mujoco, on_gl_thread, submit_gl
from sim.world import World
from vnav.camera import PinholeCamera

logger = logging.getLogger(__name__)

SKY_DOME_MIN_FRACTION = 0.696
"""Nearest ray distance of MuJoCo's skybox, as a fraction of zfar (measured, mujoco 4.0)."""
SKY_THRESHOLD_FRACTION = 0.65
"""Depth pixels whose ray is longer than this fraction of zfar are sky: set to zfar."""
SCENE_BUFFERS = 2
"""Scenes a renderer draws into in turn: one rendered on the OpenGL thread while the caller
draws the next state into the other."""
DECORATION_GEOMS = 100
"""Room in the scene's geom buffer beyond the model's own geoms, sites, cameras and lights,
for what MuJoCo adds to draw (none with the options used here; a margin, not a limit)."""


def scene_geoms(model: mujoco.MjModel) -> int:
    """Size of the scene's geom buffer (``maxgeom`` of ``mujoco.MjvScene``) for ``model``.

    MuJoCo drops whatever does not fit a full buffer (with a warning, not an error): a fixed
    size would leave out cones of a large scene. Every geom, site, camera and light of the
    model fits, and ``DECORATION_GEOMS`` more.
    """
    return model.ngeom + model.nsite + model.ncam + model.nlight + DECORATION_GEOMS


@dataclass(frozen=True)
class RenderedImage:
    """What one call of ``Renderer.render`` returns: colour, and depth and ids if asked.

    Attributes
    ----------
    rgb : np.ndarray, shape (H, W, 3), uint8
        Colour image, upright (row 0 at the top), OpenCV pixel convention.
    depth : np.ndarray, shape (H, W), float32, or None
        Planar z-depth along the optical axis, metres; where nothing was hit (sky) it reads the
        far clipping distance.
    segmentation : np.ndarray, shape (H, W), int32, or None
        MuJoCo geom id seen at each pixel, -1 for background (sky).
    time_s : float
        Simulated time of the state rendered.
    draw_s : float
        Wall seconds the OpenGL thread spent rendering and reading this image back (while
        the caller of ``render_async`` went on).
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    segmentation: np.ndarray | None
    time_s: float
    draw_s: float = 0.0


def _tan_half_fovy(scene: mujoco.MjvScene) -> float:
    """tan(fovy / 2) of the view last drawn into ``scene``, rounded to key the caches."""
    cam = scene.camera[0]
    return round((cam.frustum_top - cam.frustum_bottom) / 2.0 / cam.frustum_near, 12)


def _image_size(world: World, width: int | None, height: int | None) -> tuple[int, int]:
    """The rendered image's size: the onboard camera's unless given, checked against the
    model's off-screen buffer.

    Parameters
    ----------
    world : World
        Its camera's configured size is the default; its model's ``offwidth`` and
        ``offheight`` the limit.
    width, height : int or None
        The size asked for, pixels.

    Returns
    -------
    width, height : int
        Pixels.

    Raises
    ------
    ValueError
        If either is not positive or does not fit the off-screen buffer.
    """
    model = world.model
    width = int(width if width is not None else world.config.camera.width)
    height = int(height if height is not None else world.config.camera.height)
    if not 0 < width <= model.vis.global_.offwidth:
        raise ValueError(
            f"width must be in [1, {model.vis.global_.offwidth}] (the off-screen buffer), "
            f"got {width}"
        )
    if not 0 < height <= model.vis.global_.offheight:
        raise ValueError(
            f"height must be in [1, {model.vis.global_.offheight}] (the off-screen buffer), "
            f"got {height}"
        )
    return width, height


def _visual_option(show_drone: bool) -> mujoco.MjvOption:
    """What a view draws: the drone's geom group or not, and no sites.

    Parameters
    ----------
    show_drone : bool
        Draw ``names.DRONE_GEOM_GROUP`` (external views) or leave it out (the onboard camera:
        a real camera does not image its own housing).

    Returns
    -------
    mujoco.MjvOption
    """
    option = mujoco.MjvOption()
    option.geomgroup[names.DRONE_GEOM_GROUP] = int(show_drone)
    option.sitegroup[:] = 0
    return option


class Renderer:
    """Renders a ``World``'s cameras off-screen at the configured resolution.

    Parameters
    ----------
    world : World
        The world to render; its current state is rendered at each call.
    quality : {"fast", "high"}, optional
        Overrides ``world.config.render_quality``. ``fast``: no shadow map, no multisampling.
    width, height : int, optional
        Image size; defaults to the onboard camera's configured size. Must fit the model's
        off-screen buffer.
    gl_context : GLContext, optional
        An OpenGL context (``sim.gl.create_gl_context``) to draw in, shared with other
        renderers and owned by the caller (``sim.scene_cache.SceneCache``): a process's
        renderers after the first then cost about 10 ms instead of 200 ms (what a new context
        spends on its first ``MjrContext``). Default: a context of the renderer's own.

    Use as a context manager (or call ``close``) to free the rendering context (and the OpenGL
    context, if it is the renderer's own).
    """

    def __init__(
        self,
        world: World,
        *,
        quality: str | None = None,
        width: int | None = None,
        height: int | None = None,
        gl_context: Any = None,
    ) -> None:
        self._gl = None
        self._con = None
        self._owns_gl = gl_context is None
        self.world = world
        model = world.model
        self.width, self.height = _image_size(world, width, height)
        quality = quality if quality is not None else world.config.render_quality
        if quality not in RENDER_QUALITY:
            raise ValueError(f"quality must be one of {list(RENDER_QUALITY)}, got {quality!r}")
        self.quality = quality
        settings = RENDER_QUALITY[quality]
        on_gl_thread(self._open_contexts, gl_context, settings)

        self._scenes = [
            mujoco.MjvScene(model, maxgeom=scene_geoms(model)) for _ in range(SCENE_BUFFERS)
        ]
        # The render last queued from each scene: a scene is drawn into again only once it
        # is done. The next scene to draw into.
        self._in_flight: list[Future | None] = [None] * SCENE_BUFFERS
        self._next_scene = 0
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._depth = np.empty((self.height, self.width), dtype=np.float32)
        self._onboard_option = _visual_option(show_drone=False)
        self._external_option = _visual_option(show_drone=True)

        self._shadows = settings.shadows
        self._ray_cache: dict[float, np.ndarray] = {}
        self._sky_cache: dict[tuple[float, float], np.ndarray] = {}

    def _open_contexts(self, gl_context: Any, settings: RenderQuality) -> None:
        """Make (or take and make current) the OpenGL context, then the rendering context.

        Parameters
        ----------
        gl_context : GLContext or None
            The caller's context to draw in; None: a new one of the renderer's own.
        settings : RenderQuality
            The quality's shadow map size and multisampling (``sim.config.RENDER_QUALITY``).
        """
        model = self.world.model
        if gl_context is None:
            self._gl = create_gl_context(self.width, self.height)
        else:
            self._gl = gl_context
            self._gl.make_current()
        # The context reads shadow map size and multisampling from the model when it is made.
        saved = (model.vis.quality.shadowsize, model.vis.quality.offsamples)
        model.vis.quality.shadowsize = settings.shadowsize
        model.vis.quality.offsamples = settings.offsamples
        try:
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        finally:
            model.vis.quality.shadowsize, model.vis.quality.offsamples = saved
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR

    # ---------------------------------------------------------------- lifecycle
    def close(self) -> None:
        """Free the rendering context, and the OpenGL context if it is the renderer's own
        (idempotent; on the OpenGL thread, after the renders queued)."""
        if self._con is None and self._gl is None:
            return
        on_gl_thread(self._free)

    def _free(self) -> None:
        if self._con is not None and self._gl is not None:
            self._gl.make_current()
            self._con.free()
        self._con = None
        if self._gl is not None and self._owns_gl:
            self._gl.free()
        self._gl = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: the GL library may be gone already
            pass

    # ---------------------------------------------------------------- rendering
    def _camera(self, camera: str | int | mujoco.MjvCamera | None) -> tuple:
        """Resolve ``camera`` to (MjvCamera, is_onboard)."""
        if isinstance(camera, mujoco.MjvCamera):
            return camera, False
        model = self.world.model
        if camera is None:
            cam_id = self.world.camera_id
        elif isinstance(camera, str):
            cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if cam_id < 0:
                valid = [model.camera(i).name for i in range(model.ncam)]
                raise ValueError(f"unknown camera {camera!r}; valid cameras are {valid}")
        else:
            cam_id = int(camera)
            if not 0 <= cam_id < model.ncam:
                raise ValueError(f"camera id must be in [0, {model.ncam}), got {camera}")
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        cam.fixedcamid = cam_id
        return cam, cam_id == self.world.camera_id

    def free_camera(
        self, lookat_w: np.ndarray, distance_m: float, azimuth_deg: float, elevation_deg: float
    ) -> mujoco.MjvCamera:
        """A free (orbiting) camera looking at ``lookat_w`` for external pictures."""
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = np.asarray(lookat_w, dtype=np.float64)
        cam.distance = float(distance_m)
        cam.azimuth = float(azimuth_deg)
        cam.elevation = float(elevation_deg)
        return cam

    def render(
        self,
        *,
        depth: bool = True,
        segmentation: bool = False,
        camera: str | int | mujoco.MjvCamera | None = None,
        show_drone: bool | None = None,
    ) -> RenderedImage:
        """Render the current state (``render_async``, waited for).

        Parameters
        ----------
        depth : bool
            Also return planar z-depth (same render pass as the colour image).
        segmentation : bool
            Also return per-pixel geom ids (one extra render pass).
        camera : None, str, int or mujoco.MjvCamera
            ``None``: the onboard camera. A camera name (e.g. ``"chase"``), id, or a free
            camera from ``free_camera`` for external views.
        show_drone : bool, optional
            Draw the drone's own geoms; default: hidden for the onboard camera, shown otherwise.

        Returns
        -------
        RenderedImage
        """
        return self.render_async(
            depth=depth, segmentation=segmentation, camera=camera, show_drone=show_drone
        ).result()

    def render_async(
        self,
        *,
        depth: bool = True,
        segmentation: bool = False,
        camera: str | int | mujoco.MjvCamera | None = None,
        show_drone: bool | None = None,
    ) -> Future[RenderedImage]:
        """Draw the current state now and render it on the OpenGL thread.

        The simulation's data is read before this returns: the caller may step on at once.
        The image is the same as ``render``'s, pixel for pixel. Parameters as ``render``'s.

        Returns
        -------
        concurrent.futures.Future
            Of the ``RenderedImage``.

        Raises
        ------
        RuntimeError
            If the renderer is closed.
        ValueError
            On an unknown camera.
        """
        if self._con is None:
            raise RuntimeError("render() called after close()")
        cam, onboard = self._camera(camera)
        if show_drone is None:
            show_drone = not onboard
        option = self._external_option if show_drone else self._onboard_option
        i = self._next_scene
        self._next_scene = (i + 1) % SCENE_BUFFERS
        if self._in_flight[i] is not None:
            # Its last render must have read the scene before it is drawn into again (its
            # errors are that render's caller's: not raised here).
            self._in_flight[i].exception()
        scene = self._update_scene(i, option, cam)
        time_s = float(self.world.data.time)
        future = submit_gl(self._draw, scene, depth, segmentation, time_s)
        self._in_flight[i] = future
        return future

    def _draw(
        self, scene: mujoco.MjvScene, depth: bool, segmentation: bool, time_s: float
    ) -> RenderedImage:
        """Render ``scene`` and read it back (on the OpenGL thread)."""
        if self._con is None or self._gl is None:
            raise RuntimeError("render() called after close()")
        t0 = time.perf_counter()
        self._gl.make_current()
        if not self._owns_gl:  # another renderer in this context may have bound its buffer
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self._shadows
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        mujoco.mjr_render(self._rect, scene, self._con)
        mujoco.mjr_readPixels(self._rgb, self._depth if depth else None, self._rect, self._con)
        rgb = np.flipud(self._rgb).copy()
        depth_m = None
        if depth:
            depth_m = self._linearize(np.flipud(self._depth))
            self._sky_to_far(depth_m, scene)

        seg = None
        if segmentation:
            seg = self._segmentation(scene)
        return RenderedImage(
            rgb=rgb,
            depth=depth_m,
            segmentation=seg,
            time_s=time_s,
            draw_s=time.perf_counter() - t0,
        )

    def _update_scene(
        self, i: int, option: mujoco.MjvOption, cam: mujoco.MjvCamera
    ) -> mujoco.MjvScene:
        """Draw the current state into scene ``i``, doubling its geom buffer while it is full.

        Parameters
        ----------
        i : int
            Which of the renderer's scenes.
        option : mujoco.MjvOption
            Which geom and site groups are drawn (onboard or external).
        cam : mujoco.MjvCamera
            The camera the scene is drawn from.

        Returns
        -------
        mujoco.MjvScene
            The renderer's scene ``i`` (a larger one, kept, if the old one was full).
        """
        model, data = self.world.model, self.world.data
        scene = self._scenes[i]
        mujoco.mjv_updateScene(
            model, data, option, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scene
        )
        while scene.ngeom >= scene.maxgeom:  # full: something may be left out; grow, redraw
            logger.warning("scene geom buffer of %d full: doubled", scene.maxgeom)
            self._scenes[i] = scene = mujoco.MjvScene(model, maxgeom=2 * scene.maxgeom)
            mujoco.mjv_updateScene(
                model, data, option, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scene
            )
        return scene

    def _linearize(self, raw: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer -> planar z-depth in metres (as mujoco.Renderer does)."""
        model = self.world.model
        extent = model.stat.extent
        znear = np.float32(model.vis.map.znear * extent)
        zfar = np.float32(model.vis.map.zfar * extent)
        # OpenGL perspective matrix terms in float32, as glFrustum computes them ...
        c_coef = -(zfar + znear) / (zfar - znear)
        d_coef = -(np.float32(2) * zfar * znear) / (zfar - znear)
        # ... transformed for reversed Z (the window-to-NDC mapping is then the identity).
        c_coef = np.float32(-0.5) * c_coef - np.float32(0.5)
        d_coef = np.float32(-0.5) * d_coef
        # In float32 like the buffer itself: one pass, no float64 temporaries (the relative
        # error of the division, 6e-8, is far below the buffer's own quantisation).
        out = raw + c_coef
        np.divide(d_coef, out, out=out)
        return out

    def _sky_to_far(self, depth_m: np.ndarray, scene: mujoco.MjvScene) -> None:
        """Set sky pixels to the far clipping distance, in place.

        The skybox is drawn as a dome about the camera whose ray distance is at least
        ``SKY_DOME_MIN_FRACTION`` of ``zfar`` (measured: 0.696 zfar, wherever the camera
        is); everything real is nearer (``SceneConfig`` keeps the ground well inside it).
        """
        model = self.world.model
        zfar = float(model.vis.map.zfar * model.stat.extent)
        # ray > f zfar  <=>  depth > f zfar / (ray per depth): one compare against a cached
        # per-pixel threshold instead of a multiply and a compare per image.
        threshold_m = self._sky_threshold_m(scene, SKY_THRESHOLD_FRACTION * zfar)
        np.putmask(depth_m, depth_m > threshold_m, np.float32(zfar))

    def _sky_threshold_m(self, scene: mujoco.MjvScene, ray_limit_m: float) -> np.ndarray:
        """(H, W) planar depth beyond which a pixel's ray is longer than ``ray_limit_m``."""
        key = (_tan_half_fovy(scene), ray_limit_m)
        cached = self._sky_cache.get(key)
        if cached is None:
            cached = (ray_limit_m / self._ray_per_depth(scene)).astype(np.float32)
            self._sky_cache[key] = cached
        return cached

    def _ray_per_depth(self, scene: mujoco.MjvScene) -> np.ndarray:  # cached per fovy
        """(H, W) ray length per unit planar depth, sqrt(1 + x^2 + y^2), for the view drawn."""
        tan_half_fovy = _tan_half_fovy(scene)
        cached = self._ray_cache.get(tan_half_fovy)
        if cached is None:
            fovy_deg = math.degrees(2.0 * math.atan(tan_half_fovy))
            camera = PinholeCamera.from_fovy(fovy_deg, self.width, self.height)
            cached = camera.ray_length_per_depth().astype(np.float32)
            self._ray_cache[tan_half_fovy] = cached
        return cached

    def _segmentation(self, scene: mujoco.MjvScene) -> np.ndarray:
        """Re-render the same scene with ID colours; return per-pixel geom ids (-1: none)."""
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            mujoco.mjr_render(self._rect, scene, self._con)
            buf = np.empty((self.height, self.width, 3), dtype=np.uint8)
            mujoco.mjr_readPixels(buf, None, self._rect, self._con)
        finally:
            scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        buf = np.flipud(buf).astype(np.int64)
        segid = buf[..., 0] + (buf[..., 1] << 8) + (buf[..., 2] << 16)
        ngeom = scene.ngeom
        lut = np.full(ngeom + 1, -1, dtype=np.int32)
        for g in scene.geoms[:ngeom]:
            if g.segid != -1 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[g.segid + 1] = g.objid
        segid = np.clip(segid, 0, ngeom)
        return lut[segid]
