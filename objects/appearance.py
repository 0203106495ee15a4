"""How an object looks: a UV texture, colours per vertex or per face, or one material colour.

:class:`Appearance` is read from mesh files by the loaders (trimesh visuals), carried by
:class:`~simtest.objects.ObjectModel` and drawn by every MuJoCo model that shows objects
(:func:`add_object_visual`). Conventions:

* ``texture`` is an (H, W, 3) uint8 image with row 0 at the top (as in PNG files);
* ``face_uv`` are texture coordinates per face corner (M, 3, 2) in the OBJ / trimesh convention: ``u`` to
  the right, ``v`` up, ``(0, 0)`` at the bottom-left of the image. Storing them per corner keeps UV seams
  while the geometry stays one closed mesh (watertight for physics and mass).

MuJoCo has no vertex colours, so colours per vertex are *baked* into a texture: each face gets one texel of
a square atlas holding the mean colour of its three vertices, and all three of its corners get that texel's
centre as UV. A UV that is constant over a face samples exactly that texel at any distance and with any
filter or mip level (its screen-space derivatives are zero), so every face shows exactly its colour and no
neighbour bleeds in; scanned models with vertex colours (BOP's LM, YCB-V) have faces of a few millimetres,
below a pixel at working distances, so the mean over a face loses nothing visible. MuJoCo stores the result
in standard model fields (``tex_*``, ``mat_texid``, ``mesh_texcoord``, ``mesh_facetexcoord``).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import numpy as np

from simtest.errors import AssetError

__all__ = ["Appearance", "appearance_from_visual", "render_texture", "surface_colors", "tint_rgba",
           "add_object_visual", "texture_roles"]


@dataclass(frozen=True, eq=False)
class Appearance:
    """The colours of a mesh beyond its material colour (at most one kind is set).

    Attributes:
        texture: (H, W, 3) uint8 image, row 0 at the top; with ``face_uv``.
        face_uv: (M, 3, 2) float64 UV per face corner (``v`` up, origin at the image's bottom-left).
        vertex_colors: (N, 3) uint8 colour per mesh vertex.
        face_colors: (M, 3) uint8 colour per face.
    """

    texture: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("texture", "face_uv", "vertex_colors", "face_colors"):
            value = getattr(self, name)
            if value is not None:
                arr = np.array(value, dtype=np.float64 if name == "face_uv" else np.uint8)
                arr.flags.writeable = False
                object.__setattr__(self, name, arr)
        if (self.texture is None) != (self.face_uv is None):
            raise AssetError("appearance: a texture needs face_uv and face_uv needs a texture")

    @property
    def kind(self) -> str:
        """``"texture"``, ``"vertex"``, ``"face"`` or ``"none"``."""
        if self.texture is not None:
            return "texture"
        if self.vertex_colors is not None:
            return "vertex"
        return "face" if self.face_colors is not None else "none"

    def check(self, n_vertices: int, n_faces: int, where: str) -> None:
        """Raise :class:`AssetError` naming ``where`` unless the arrays fit a mesh of this size."""
        tests = [("texture", self.texture, lambda a: a.ndim == 3 and a.shape[2] == 3 and min(a.shape[:2]) > 0,
                  "(H, W, 3)"),
                 ("face_uv", self.face_uv, lambda a: a.shape == (n_faces, 3, 2), f"({n_faces}, 3, 2)"),
                 ("vertex_colors", self.vertex_colors, lambda a: a.shape == (n_vertices, 3), f"({n_vertices}, 3)"),
                 ("face_colors", self.face_colors, lambda a: a.shape == (n_faces, 3), f"({n_faces}, 3)")]
        for name, arr, ok, want in tests:
            if arr is not None and not ok(arr):
                raise AssetError(f"{where}: appearance.{name} has shape {arr.shape}, expected {want}")
        if self.face_uv is not None and not np.all(np.isfinite(self.face_uv)):
            raise AssetError(f"{where}: appearance.face_uv has NaN or infinite texture coordinates")


def _image_of(material) -> np.ndarray | None:
    """The base-colour image (H, W, 3) uint8 of a trimesh material, if it has one."""
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    return np.asarray(image.convert("RGB"), dtype=np.uint8)


def appearance_from_visual(visual, faces: np.ndarray) -> tuple[Appearance | None, tuple | None]:
    """Appearance and material colour of a trimesh visual, for the mesh's ``faces`` as loaded.

    Args:
        visual: ``mesh.visual`` of a mesh loaded with ``process=False`` (vertices split at UV seams).
        faces: (M, 3) faces of that mesh.

    Returns:
        ``(appearance or None, rgba or None)``: per-vertex colours are returned per vertex of the loaded mesh
        (the loader maps them to merged vertices); a texture's material colour multiplies it (glTF
        ``baseColorFactor``; white for OBJ and PLY).
    """
    kind = getattr(visual, "kind", None)
    faces = np.asarray(faces)
    if kind == "texture":
        material = getattr(visual, "material", None)
        image = _image_of(material) if material is not None else None
        uv = getattr(visual, "uv", None)
        factor = getattr(material, "baseColorFactor", None)
        rgba = None if factor is None else tuple(float(c) / 255.0 for c in np.asarray(factor)[:4])
        if image is not None and uv is not None and len(uv) > int(faces.max()):
            uv = np.asarray(uv, dtype=np.float64)[:, :2]
            return Appearance(texture=image, face_uv=uv[faces]), rgba or (1.0, 1.0, 1.0, 1.0)
        main = getattr(material, "main_color", None)
        return None, None if main is None else tuple(float(c) / 255.0 for c in np.asarray(main)[:3]) + (1.0,)
    if kind in ("vertex", "face"):
        colors = np.asarray(visual.vertex_colors if kind == "vertex" else visual.face_colors)[:, :3].astype(np.uint8)
        if len(colors) and np.all(colors == colors[0]):
            return None, tuple(float(c) / 255.0 for c in colors[0]) + (1.0,)
        app = Appearance(vertex_colors=colors) if kind == "vertex" else Appearance(face_colors=colors)
        return app, (1.0, 1.0, 1.0, 1.0)
    return None, None


def render_texture(appearance: Appearance, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The texture and UVs that draw ``appearance`` on a mesh with ``faces`` (None for ``kind == "none"``).

    Textures are returned as they are; colours per vertex or per face are baked into a square atlas with one
    texel per face (see the module docstring for why this is exact).

    Returns:
        ``(image (H, W, 3) uint8 with row 0 at the top, face_uv (M, 3, 2) with v up)``.
    """
    if appearance.kind == "texture":
        return appearance.texture, appearance.face_uv
    if appearance.kind == "none":
        return None
    faces = np.asarray(faces)
    if appearance.kind == "vertex":
        colors = np.rint(appearance.vertex_colors[faces].astype(np.float64).mean(axis=1)).astype(np.uint8)
    else:
        colors = appearance.face_colors
    m = len(faces)
    side = max(1, math.ceil(math.sqrt(m)))
    atlas = np.zeros((side * side, 3), dtype=np.uint8)
    atlas[:m] = colors
    idx = np.arange(m)
    row, col = idx // side, idx % side
    uv = np.stack([(col + 0.5) / side, 1.0 - (row + 0.5) / side], axis=1)
    return atlas.reshape(side, side, 3), np.repeat(uv[:, None, :], 3, axis=1)


def surface_colors(appearance: Appearance, faces: np.ndarray, face_index: np.ndarray, barycentric: np.ndarray
                   ) -> np.ndarray:
    """(N, 3) colours in [0, 1] of surface points given by their face and barycentric coordinates (N, 3):
    the texel under the interpolated UV (nearest, UVs wrapped to [0, 1)), the interpolated vertex colours, or
    the face's colour. Raises :class:`AssetError` for ``kind == "none"``."""
    f = np.asarray(face_index, dtype=np.int64)
    b = np.asarray(barycentric, dtype=np.float64)
    if appearance.kind == "texture":
        uv = np.einsum("nk,nkj->nj", b, appearance.face_uv[f]) % 1.0
        H, W = appearance.texture.shape[:2]
        col = np.clip(np.floor(uv[:, 0] * W), 0, W - 1).astype(np.int64)
        row = np.clip(np.floor((1.0 - uv[:, 1]) * H), 0, H - 1).astype(np.int64)
        return appearance.texture[row, col].astype(np.float64) / 255.0
    if appearance.kind == "vertex":
        corners = appearance.vertex_colors[np.asarray(faces)[f]].astype(np.float64)
        return np.einsum("nk,nkj->nj", b, corners) / 255.0
    if appearance.kind == "face":
        return appearance.face_colors[f].astype(np.float64) / 255.0
    raise AssetError("surface_colors: the appearance has no colours (kind 'none')")


def tint_rgba(amount: float, rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A mild multiplicative tint of a textured object: its texture times this colour (MuJoCo multiplies a
    texture by its material colour), so the object keeps its own appearance.

    ``amount`` in [0, 1]: brightness is drawn in ``[1 - amount, 1]``, hue anywhere and saturation in
    ``[0, amount / 2]``; 0 gives white (no change).
    """
    value = 1.0 - float(rng.uniform(0.0, amount))
    hue = float(rng.uniform(0.0, 1.0))
    sat = float(rng.uniform(0.0, amount / 2.0))
    r, g, b = colorsys.hsv_to_rgb(hue, sat, value)
    return (float(r), float(g), float(b), 1.0)


def add_object_visual(spec, obj, mesh_name: str) -> tuple[object, str | None]:
    """Add ``obj``'s visual mesh (named ``mesh_name``) to a ``mujoco.MjSpec``, with texture coordinates and a
    texture named ``mesh_name + "_tex"`` when the object has an appearance.

    Returns:
        ``(the MjsMesh, the texture name or None)``: None when the object has only a material colour.
        Materials that show the texture set it in their RGB role (:func:`texture_roles`).
    """
    mesh = spec.add_mesh(name=mesh_name)
    mesh.uservert = np.asarray(obj.vertices, dtype=np.float64).reshape(-1).tolist()
    mesh.userface = np.asarray(obj.faces, dtype=np.int32).reshape(-1).tolist()
    baked = None if obj.appearance is None else render_texture(obj.appearance, obj.faces)
    if baked is None:
        return mesh, None
    image, face_uv = baked
    # MuJoCo's user texture coordinates put v = 0 at the first image row (the top): flip v.
    corners = np.column_stack([face_uv[..., 0].reshape(-1), 1.0 - face_uv[..., 1].reshape(-1)])
    texcoord, index = np.unique(corners, axis=0, return_inverse=True)
    mesh.usertexcoord = texcoord.reshape(-1).tolist()
    mesh.userfacetexcoord = np.asarray(index, dtype=np.int32).reshape(-1).tolist()
    import mujoco

    h, w = image.shape[:2]
    tex = spec.add_texture(name=f"{mesh_name}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, width=w, height=h,
                           nchannel=3)
    tex.data = np.ascontiguousarray(image, dtype=np.uint8).tobytes()
    return mesh, f"{mesh_name}_tex"


def texture_roles(texture: str) -> list[str]:
    """The ``MjsMaterial.textures`` list that shows ``texture`` as the material's colour (RGB role)."""
    import mujoco

    roles = [""] * int(mujoco.mjtTextureRole.mjNTEXROLE)
    roles[int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] = texture
    return roles
