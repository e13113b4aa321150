"""Ray/mesh visibility by rasterisation (moderngl, EGL): camera G-buffers and projector depth maps.

One standalone EGL context per :class:`MeshRaster`; use it from one thread
and :meth:`MeshRaster.close` it when the precomputation is done. Shaders live
in ``sim/shaders/``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.errors import RenderError
from sim.geometry import Pinhole
from sim.mesh import Mesh

SHADERS = Path(__file__).resolve().parent / "shaders"


def _shader(name: str) -> str:
    return (SHADERS / name).read_text()


def create_context():
    """A standalone moderngl context on EGL (Mesa's llvmpipe where there is no GPU)."""
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise RenderError("moderngl is not installed; install shadowless with the 'sim' extra") from exc
    try:
        return moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # moderngl raises plain Exception subclasses
        raise RenderError(
            f"cannot create an OpenGL context through EGL ({exc}); install Mesa's EGL and GL drivers "
            "(e.g. apt-get install libegl1 libgl1 libgl1-mesa-dri) or run on a machine with a GPU"
        ) from exc


class MeshRaster:
    """Rasterises one mesh from cameras and projectors.

    Parameters
    ----------
    mesh : Mesh
        Needs ``uvs`` for :meth:`gbuffer`'s uv output (zeros otherwise).
    """

    def __init__(self, mesh: Mesh) -> None:
        self.mesh = mesh
        self.ctx = create_context()
        try:
            normals = mesh.vertex_normals()
            uvs = mesh.uvs if mesh.uvs is not None else np.zeros((len(mesh.vertices), 2), np.float32)
            data = np.hstack([mesh.vertices, normals, uvs]).astype("f4")
            self._vbo = self.ctx.buffer(data.tobytes())
            self._ibo = self.ctx.buffer(mesh.faces.astype("u4").tobytes())
            self._gprog = self.ctx.program(vertex_shader=_shader("gbuffer.vert.glsl"), fragment_shader=_shader("gbuffer.frag.glsl"))
            self._dprog = self.ctx.program(vertex_shader=_shader("depth.vert.glsl"), fragment_shader=_shader("depth.frag.glsl"))
            self._gvao = self.ctx.vertex_array(self._gprog, [(self._vbo, "3f 3f 2f", "in_position", "in_normal", "in_uv")], self._ibo)
            self._dvao = self.ctx.vertex_array(self._dprog, [(self._vbo, "3f 20x", "in_position")], self._ibo)
        except Exception:
            self.close()
            raise
        lo, hi = mesh.bounds
        self._corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    def _near_far(self, device: Pinhole) -> tuple[float, float]:
        z = self.mesh_depths(device)
        far = float(z.max()) * 1.01 + 10.0
        near = max(1.0, float(z.min()) * 0.99 - 10.0)
        return near, max(far, near * 1.5)

    def mesh_depths(self, device: Pinhole) -> np.ndarray:
        """Depths (mm) of the mesh's bounding-box corners along the device axis."""
        return device.to_device(self._corners)[:, 2]

    def gbuffer(self, device: Pinhole) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What each pixel of ``device`` sees of the mesh.

        Returns
        -------
        position : (H, W, 3) float32
            World mm of the nearest surface (undefined where not ``hit``).
        normal : (H, W, 3) float32
            Interpolated unit vertex normal.
        uv : (H, W, 2) float32
            Content uv of the mesh at the pixel.
        hit : (H, W) bool
        """
        w, h = device.size
        near, far = self._near_far(device)
        if far <= 1.0:
            empty = np.zeros((h, w), bool)
            return np.zeros((h, w, 3), np.float32), np.zeros((h, w, 3), np.float32), np.zeros((h, w, 2), np.float32), empty
        textures = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(3)]
        depth = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=textures, depth_attachment=depth)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self._gprog["mvp"].write(device.gl_projection(near=near, far=far).T.astype("f4").tobytes())
            self._gvao.render()
            out = [np.frombuffer(fbo.read(components=4, attachment=k, dtype="f4"), np.float32).reshape(h, w, 4) for k in range(3)]
        finally:
            fbo.release()
            depth.release()
            for t in textures:
                t.release()
        pos, nrm, uv = out
        hit = pos[..., 3] > 0.5
        return pos[..., :3].copy(), nrm[..., :3].copy(), uv[..., :2].copy(), hit

    def depth_map(self, device: Pinhole) -> np.ndarray:
        """Nearest mesh depth (mm along the axis) per pixel of ``device``; ``inf`` where empty.

        Returns
        -------
        (H, W) float32
        """
        w, h = device.size
        near, far = self._near_far(device)
        if far <= 1.0:
            return np.full((h, w), np.inf, np.float32)
        tex = self.ctx.texture((w, h), 1, dtype="f4")
        depth = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer(color_attachments=[tex], depth_attachment=depth)
        try:
            fbo.use()
            fbo.clear(np.inf, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.ctx.disable(self.ctx.CULL_FACE)
            self._dprog["mvp"].write(device.gl_projection(near=near, far=far).T.astype("f4").tobytes())
            zrow = np.append(device.R[2], device.t[2]).astype("f4")
            self._dprog["zrow"].write(zrow.tobytes())
            self._dvao.render()
            d = np.frombuffer(fbo.read(components=1, dtype="f4"), np.float32).reshape(h, w).copy()
        finally:
            fbo.release()
            depth.release()
            tex.release()
        return d

    def close(self) -> None:
        ctx = getattr(self, "ctx", None)
        if ctx is not None:
            ctx.release()
            self.ctx = None

    def __enter__(self) -> "MeshRaster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
