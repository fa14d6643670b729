"""shellspline for Blender: interpolate a mesh's shape keys by a spline in the space of shells.

Installed as the add-on package ``shellspline_addon`` (``shellspline blender-addon -o
shellspline_addon.zip``, then Blender > Edit > Preferences > Add-ons > Install from Disk).
The operator *Object > Animation > Shellspline: Interpolate Shape Keys* (also in the 3D
view's sidebar, tab *Shellspline*) takes the active mesh's shape keys as keyframes

* at the frames where they are keyed (``timing="KEYED"``: every frame with a keyframe on a
  shape-key value; the pose there is the mesh with its shape-key animation, modifiers off), or
* evenly spaced (``timing="EVEN"``: Basis (optional) and the shape keys in list order at
  ``frame_start``, ``frame_start + frame_step``, ...),

interpolates every frame between the first and the last keyframe and bakes the result as
shape keys ``shellspline.NNNN`` keyed 0-1-0 around their frame (linear), or as a PC2 point
cache read by a *Mesh Cache* modifier named ``shellspline``. The source shape keys are muted
while baked shape keys play (unmuted again when the bake is replaced). One undo step;
progress in the status bar; problems the solver reports (stalled frames, flipped faces,
folds, pops) come back as warnings. How shellspline is found: see :mod:`.engine` and the
README.
"""
from __future__ import annotations

import os

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from . import engine  # shellspline_addon/engine.py in the zip (integrations/blender/engine.py)

bl_info = {
    "name": "shellspline",
    "author": "shellspline authors",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > Shellspline; Object > Animation",
    "description": "Smooth in-betweens of shape-key keyframes: splines in the space of shells",
    "category": "Animation",
}

PREFIX = "shellspline."
MODIFIER = "shellspline"
_MUTED = "shellspline_muted"  # object custom property: source keys muted by the last bake


def _enum(values, descriptions):
    return [(v, v, d) for v, d in zip(values, descriptions)]


class ShellsplinePreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    backend: EnumProperty(
        name="Back end", default="auto",
        items=[("auto", "Automatic", "The library if Blender's Python can import shellspline, "
                                     "else the executable"),
               ("library", "Library", "import shellspline in Blender's Python"),
               ("cli", "Executable", "run an external shellspline command")])
    executable: StringProperty(
        name="shellspline executable", subtype="FILE_PATH", default="",
        description="Path of the shellspline command of another Python environment (empty: "
                    "found on PATH)")

    def draw(self, context):
        self.layout.prop(self, "backend")
        self.layout.prop(self, "executable")
        self.layout.label(text="library importable: "
                               + ("yes" if engine.library_available() else "no"))


def _preferences(context):
    addon = context.preferences.addons.get(__package__)
    return getattr(addon, "preferences", None)


def _key_fcurves(key):
    """The F-curves of a shape-key datablock's action (legacy and layered actions)."""
    ad = key.animation_data if key else None
    act = ad.action if ad else None
    if act is None:
        return []
    fcurves = getattr(act, "fcurves", None)
    if fcurves is not None:  # Blender < 5.0
        return list(fcurves)
    out = []  # pragma: no cover - layered actions (Blender 5)
    for layer in act.layers:
        for strip in layer.strips:
            bag = strip.channelbag(ad.action_slot)
            if bag is not None:
                out += list(bag.fcurves)
    return out


def _positions(mesh_like) -> np.ndarray:
    co = np.zeros(3 * len(mesh_like), dtype=np.float64)
    mesh_like.foreach_get("co", co)
    return co.reshape(-1, 3)


def _triangles(me) -> np.ndarray:
    me.calc_loop_triangles()
    F = np.zeros(3 * len(me.loop_triangles), dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", F)
    return F.reshape(-1, 3)


def _pinned(ob, name) -> np.ndarray | None:
    if not name:
        return None
    vg = ob.vertex_groups.get(name)
    if vg is None:
        raise ValueError(f"vertex group {name!r} not found on {ob.name!r}")
    idx = vg.index  # Blender has no bulk read of group weights
    pins = [v.index for v in ob.data.vertices if any(g.group == idx and g.weight > 0
                                                     for g in v.groups)]
    if not pins:
        raise ValueError(f"vertex group {name!r} is empty")
    return np.asarray(pins, dtype=np.int64)


def _remove_previous_bake(ob) -> None:
    key = ob.data.shape_keys
    if key is not None:
        ours = [kb for kb in key.key_blocks if kb.name.startswith(PREFIX)]
        for fc in _key_fcurves(key):
            if fc.data_path.startswith(f'key_blocks["{PREFIX}'):
                fc.id_data.fcurves.remove(fc)  # id_data: the action
        for kb in ours:
            ob.shape_key_remove(kb)
        for name in ob.get(_MUTED, []):
            if name in key.key_blocks:
                key.key_blocks[name].mute = False
    if _MUTED in ob:
        del ob[_MUTED]
    mod = ob.modifiers.get(MODIFIER)
    if mod is not None:
        ob.modifiers.remove(mod)


def keyframes_of(context, ob, timing="KEYED", use_basis=True, frame_start=1, frame_step=10):
    """Keyframe poses ``(J,n,3)`` and their frames ``(J,)`` from ``ob``'s shape keys."""
    key = ob.data.shape_keys
    if key is None or len(key.key_blocks) < 2:
        raise ValueError(f"{ob.name!r} needs shape keys (at least Basis and one more)")
    if timing == "EVEN":
        blocks = [kb for kb in key.key_blocks if not kb.name.startswith(PREFIX)]
        if not use_basis:
            blocks = blocks[1:]
        if len(blocks) < 2:
            raise ValueError(f"{ob.name!r}: need at least two shape keys as keyframes")
        V = np.stack([_positions(kb.data) for kb in blocks])
        return V, frame_start + frame_step * np.arange(len(blocks)), [kb.name for kb in blocks]
    frames = sorted({int(round(p.co[0])) for fc in _key_fcurves(key)
                     if fc.data_path.startswith("key_blocks[") or fc.data_path == "eval_time"
                     for p in fc.keyframe_points})
    if len(frames) < 2:
        raise ValueError(f"{ob.name!r}: its shape keys are keyed at {len(frames)} frame(s); "
                         "key them at two frames or more, or use evenly spaced shape keys")
    scene, current = context.scene, context.scene.frame_current
    shown = [(m, m.show_viewport) for m in ob.modifiers]
    try:
        for m, _ in shown:
            m.show_viewport = False
        V = []
        for f in frames:
            scene.frame_set(f)
            ev = ob.evaluated_get(context.evaluated_depsgraph_get())
            me = ev.to_mesh()
            V.append(_positions(me.vertices))
            ev.to_mesh_clear()
    finally:
        for m, state in shown:
            m.show_viewport = state
        scene.frame_set(current)
    return np.stack(V), np.asarray(frames), [f"frame {f}" for f in frames]


def bake_shape_keys(ob, V, start) -> list:
    """Add shape keys ``shellspline.NNNN`` holding ``V[k]`` keyed 1 at frame ``start + k`` and 0
    at the neighbouring frames (linear); mute the other shape keys. Returns the muted names."""
    key = ob.data.shape_keys
    muted = [kb.name for kb in key.key_blocks[1:] if not kb.mute]
    for name in muted:
        key.key_blocks[name].mute = True
    ob[_MUTED] = muted
    edit = bpy.context.preferences.edit
    before = edit.keyframe_new_interpolation_type
    edit.keyframe_new_interpolation_type = "LINEAR"
    try:
        K = V.shape[0] - 1
        for k in range(K + 1):
            kb = ob.shape_key_add(name=f"{PREFIX}{start + k:04d}", from_mix=False)
            kb.data.foreach_set("co", V[k].astype(np.float32).ravel())
            for dk, value in ((-1, 0.0), (0, 1.0), (1, 0.0)):
                if 0 <= k + dk <= K:
                    kb.value = value
                    kb.keyframe_insert("value", frame=start + k + dk)
    finally:
        edit.keyframe_new_interpolation_type = before
    return muted


def bake_cache(ob, V, start, filepath) -> str:
    """Write ``V`` as a PC2 file and play it with a Mesh Cache modifier (first in the stack)."""
    path = bpy.path.abspath(filepath)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    engine.write_pc2(path, V, start_frame=start)
    mod = ob.modifiers.new(MODIFIER, "MESH_CACHE")
    mod.cache_format, mod.filepath = "PC2", filepath
    mod.time_mode, mod.play_mode, mod.frame_start = "FRAME", "SCENE", float(start)
    ob.modifiers.move(len(ob.modifiers) - 1, 0)
    return path


class SHELLSPLINE_OT_interpolate(bpy.types.Operator):
    """Interpolate the active mesh's shape keys by a spline in the space of shells and bake the
    in-betweens"""

    bl_idname = "object.shellspline_interpolate"
    bl_label = "Shellspline: Interpolate Shape Keys"
    bl_options = {"REGISTER", "UNDO"}

    timing: EnumProperty(name="Keyframes", default="KEYED", items=[
        ("KEYED", "Keyed frames", "Poses at the frames where shape-key values are keyed"),
        ("EVEN", "Evenly spaced", "Basis (optional) and the shape keys in order, evenly "
                                  "spaced")])
    use_basis: BoolProperty(name="Basis is the first keyframe", default=True)
    frame_start: IntProperty(name="First frame", default=1)
    frame_step: IntProperty(name="Frames between keys", default=10, min=1)
    frame_end: IntProperty(name="Last frame", default=0, min=0,
                           description="0: the last keyframe (periodic: the frame before the "
                                       "loop closes)")
    method: EnumProperty(name="Method", default="lta", items=_enum(engine.METHODS, (
        "LΘA shell spline (fast)", "per-vertex linear blend (baseline)",
        "piecewise discrete geodesics", "nonlinear shell spline (slow)")))
    bc: EnumProperty(name="Boundary", default="natural", items=_enum(
        engine.BOUNDARY_CONDITIONS, ("natural spline ends", "loop",
                                     "keys at the 2nd and 2nd-last frame fix the end velocities")))
    eta: FloatProperty(name="η (bending)", default=1e-3, min=1e-9, precision=6,
                       description="bending weight, thickness squared")
    coarse: StringProperty(name="Coarse", default="auto",
                           description="multiresolution: auto, none, a vertex count or a "
                                       "fraction")
    fine: BoolProperty(name="Refine at full resolution", default=False)
    rigid_track: EnumProperty(name="Rigid track", default="fit", items=_enum(
        engine.RIGID_TRACKS, ("per-vertex cubic", "SE(3) spline", "linear blend")))
    max_iter: IntProperty(name="Gauss-Newton iterations", default=0, min=0,
                          description="0: the library's default")
    pin_group: StringProperty(name="Pinned group", default="",
                              description="vertex group held fixed")
    output: EnumProperty(name="Bake to", default="SHAPE_KEYS", items=[
        ("SHAPE_KEYS", "Shape keys", "one shape key per frame, keyed"),
        ("CACHE", "Point cache", "a PC2 file and a Mesh Cache modifier")])
    cache_path: StringProperty(name="Cache file", subtype="FILE_PATH", default="",
                               description="PC2 file (default: next to the .blend file)")

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        return ob is not None and ob.type == "MESH" and ob.mode == "OBJECT"

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        lay = self.layout
        lay.prop(self, "timing")
        if self.timing == "EVEN":
            lay.prop(self, "use_basis")
            lay.prop(self, "frame_start")
            lay.prop(self, "frame_step")
        for name in ("frame_end", "method", "bc", "eta", "coarse", "fine", "rigid_track",
                     "max_iter"):
            lay.prop(self, name)
        ob = context.active_object
        if ob is not None:
            lay.prop_search(self, "pin_group", ob, "vertex_groups")
        lay.prop(self, "output")
        if self.output == "CACHE":
            lay.prop(self, "cache_path")

    def _cache_path(self, ob) -> str:
        if self.cache_path:
            return self.cache_path
        name = bpy.path.clean_name(ob.name) + ".pc2"
        if bpy.data.filepath:
            return "//shellspline_" + name
        return os.path.join(bpy.app.tempdir or os.getcwd(), "shellspline_" + name)

    def execute(self, context):
        ob = context.active_object
        wm = context.window_manager
        status = getattr(context.workspace, "status_text_set", None)
        wm.progress_begin(0, 1000)

        def progress(fraction, text):
            wm.progress_update(int(1000 * fraction))
            if status is not None:
                status(f"shellspline: {text} {100 * fraction:.0f}%")

        try:
            _remove_previous_bake(ob)
            V, frames, _ = keyframes_of(context, ob, self.timing, self.use_basis,
                                        self.frame_start, self.frame_step)
            K = self.frame_end - int(frames[0]) if self.frame_end else None
            if K is not None and K < frames[-1] - frames[0]:
                raise ValueError(f"last frame {self.frame_end} comes before the last keyframe "
                                 f"{int(frames[-1])}")
            prefs = _preferences(context)
            eta = float("%.7g" % self.eta)  # Blender stores float32: 1e-3, not 0.0010000000475
            opts = engine.Options(self.method, self.bc, eta, self.coarse, self.fine,
                                  self.rigid_track, self.max_iter)
            res = engine.interpolate(V, _triangles(ob.data), frames, K=K, options=opts,
                                     pinned=_pinned(ob, self.pin_group),
                                     backend=getattr(prefs, "backend", "auto"),
                                     executable=getattr(prefs, "executable", ""),
                                     progress=progress)
            if self.output == "SHAPE_KEYS":
                bake_shape_keys(ob, res.V, res.start)
                where = f"{res.V.shape[0]} shape keys {PREFIX}NNNN"
            else:
                path = bake_cache(ob, res.V, res.start, self._cache_path(ob))
                where = f"{path} (Mesh Cache modifier '{MODIFIER}')"
        except Exception as exc:  # noqa: BLE001 - every failure becomes one report line
            self.report({"ERROR"}, f"shellspline: {type(exc).__name__}: {exc}")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
            if status is not None:
                status(None)
        end = res.start + res.V.shape[0] - 1
        self.report({"INFO"}, f"shellspline ({res.backend}): frames {res.start}-{end} baked as "
                              f"{where}")
        for line in res.problems:
            self.report({"WARNING"}, "shellspline: " + line)
        return {"FINISHED"}


class SHELLSPLINE_PT_panel(bpy.types.Panel):
    bl_label = "Shellspline"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Shellspline"

    def draw(self, context):
        ob = context.active_object
        keys = ob.data.shape_keys if ob is not None and ob.type == "MESH" else None
        self.layout.label(text=f"{len(keys.key_blocks) if keys else 0} shape keys")
        self.layout.operator(SHELLSPLINE_OT_interpolate.bl_idname, text="Interpolate")


def _menu(self, context):
    self.layout.operator(SHELLSPLINE_OT_interpolate.bl_idname)


_CLASSES = (ShellsplinePreferences, SHELLSPLINE_OT_interpolate, SHELLSPLINE_PT_panel)


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.VIEW3D_MT_object_animation.append(_menu)


def unregister():
    bpy.types.VIEW3D_MT_object_animation.remove(_menu)
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
