# SPDX-License-Identifier: GPL-3.0-or-later
"""photongrid render engine for Blender 4.2+ (an extension; also Blender 5.x).

F12 exports the scene with Blender's glTF exporter, runs the ``photongrid`` binary for the
active camera and loads its EXR into the render result. The work is done by ``core`` (plain
Python); this module is the Blender glue: the engine, the settings panel, the preferences.
"""

import os
import shutil
import tempfile
import traceback

import bpy
from bpy.props import EnumProperty, IntProperty, PointerProperty, StringProperty, BoolProperty

from . import core

ENGINE_ID = "PHOTONGRID"


# --------------------------------------------------------------------------------------
# Preferences


class PhotongridPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    binary_path: StringProperty(
        name="photongrid Binary",
        description=(
            "Path of the photongrid executable. Empty: the PHOTONGRID_BIN environment variable, "
            "then photongrid on PATH"
        ),
        subtype="FILE_PATH",
        default="",
    )
    keep_temp_files: BoolProperty(
        name="Keep Temporary Files",
        description="Keep the exported .glb and the rendered .exr (their folder is printed on the console)",
        default=False,
    )

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "binary_path")
        layout.prop(self, "keep_temp_files")
        try:
            layout.label(text=f"Using: {core.find_binary(bpy.path.abspath(self.binary_path))}", icon="CHECKMARK")
        except core.PhotongridError as e:
            layout.label(text=str(e), icon="ERROR")


def preferences():
    """The add-on's preferences, or None when it was registered without the add-on system
    (e.g. ``register()`` called from a script or test): then env/PATH are used."""
    context_prefs = getattr(bpy.context, "preferences", None)
    addons = getattr(context_prefs, "addons", None)
    if addons is None:
        return None
    addon = addons.get(__package__)
    return getattr(addon, "preferences", None) if addon else None


def configured_binary() -> str:
    prefs = preferences()
    path = getattr(prefs, "binary_path", "") if prefs else ""
    return bpy.path.abspath(path) if path else ""


# --------------------------------------------------------------------------------------
# Scene settings


class PhotongridSceneSettings(bpy.types.PropertyGroup):
    photons: IntProperty(
        name="Photons",
        description="Photon paths emitted from the lights",
        default=2_000_000,
        min=1,
        soft_max=50_000_000,
    )
    neighbours: IntProperty(
        name="Neighbours",
        description="Photons per radiance estimate (k nearest neighbours)",
        default=100,
        min=1,
        soft_max=1000,
    )
    spp: IntProperty(
        name="Samples",
        description="Camera rays per pixel",
        default=4,
        min=1,
        soft_max=256,
    )
    seed: IntProperty(
        name="Seed",
        description="Random seed: the same seed and settings give the same image",
        default=0,
        min=0,
    )
    direct: EnumProperty(
        name="Direct Lighting",
        description="Where direct light comes from",
        items=[
            ("SHADOW_RAYS", "Shadow Rays", "Shadow rays to every light; photons give indirect light and caustics"),
            ("PHOTONS", "Photons", "All light from photons, like the paper's single photon map"),
        ],
        default="SHADOW_RAYS",
    )
    method: EnumProperty(
        name="Method",
        description="Radius of the photon estimate (--method)",
        items=[
            ("DEFAULT", "Default", "The renderer's default (adaptive)"),
            ("KNN", "kNN", "Classic k nearest neighbours"),
            ("ADAPTIVE", "Adaptive", "The paper's grid-adaptive radius"),
            ("SPPM", "SPPM", "Stochastic progressive photon mapping (use with a time budget)"),
        ],
        default="DEFAULT",
    )
    grid: EnumProperty(
        name="Grid",
        description="Grids of the adaptive method (--grid)",
        items=[
            ("DEFAULT", "Default", "The renderer's default (auto)"),
            ("AUTO", "Auto", "Plane grids for planes, voxels where needed"),
            ("PLANES", "Planes", "Plane grids only, as the paper"),
            ("VOXELS", "Voxels", "One sparse voxel grid for every surface"),
            ("NONE", "None", "No grid: plain kNN"),
        ],
        default="DEFAULT",
    )
    time_budget: StringProperty(
        name="Time Budget",
        description="Time budget (--time-budget, e.g. 30s); passed only if set, for photongrid versions that have it",
        default="",
    )


# --------------------------------------------------------------------------------------
# The engine


class PhotongridRenderEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "photongrid"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_eevee_viewport = True

    def render(self, depsgraph):
        if self.is_preview:
            return
        scene = depsgraph.scene
        width, height = self.resolution_x, self.resolution_y
        if width <= 0 or height <= 0:
            width, height = core.render_size(scene)
        camera = self.camera_override or scene.camera
        try:
            binary = core.find_binary(configured_binary())
            if camera is None:
                raise core.PhotongridError("the scene has no active camera: set one in Scene properties > Camera")
            self._render(scene, binary, camera.name, width, height)
        except core.Cancelled:
            self.update_stats("", "photongrid: cancelled")
        except core.PhotongridError as e:
            self.fail(str(e))
        except Exception as e:  # noqa: BLE001 - a bug here must not look like a finished render
            traceback.print_exc()
            self.fail(f"photongrid add-on error: {type(e).__name__}: {e}")

    def _render(self, scene, binary, camera_name, width, height):
        prefs = preferences()
        keep = bool(getattr(prefs, "keep_temp_files", False))
        base = getattr(self, "temporary_directory", "") or None
        if base and not os.path.isdir(base):
            base = None
        workdir = tempfile.mkdtemp(prefix="photongrid-", dir=base)
        try:
            path = core.run_photongrid(
                scene,
                workdir,
                binary,
                settings=core.settings_from_scene(scene),
                camera=camera_name,
                size=(width, height),
                on_status=self.show_status,
                on_progress=self.show_progress,
                should_cancel=self.cancel_requested,
            )
            self.update_stats("", "photongrid: loading image")
            pixels = core.read_exr_rgba(path, width, height)
            result = self.begin_result(0, 0, width, height)
            try:
                # RenderLayer.load_from_file wants a multilayer EXR ("ViewLayer.Combined.R"), so
                # the pixels of the CLI's plain RGB EXR are set on the Combined pass. photongrid
                # renders the whole scene: every view layer gets the same image.
                for layer in result.layers:
                    layer.passes["Combined"].rect.foreach_set(pixels)
            finally:
                self.end_result(result)
            self.update_stats("", "photongrid: done")
        finally:
            if keep:
                print(f"photongrid: temporary files kept in {workdir}")
            else:
                shutil.rmtree(workdir, ignore_errors=True)

    def show_status(self, text):
        """The phase, in the render window's header and the status bar."""
        self.update_stats("", text)

    def show_progress(self, fraction):
        self.update_progress(fraction)

    def cancel_requested(self):
        """Esc pressed (polled while photongrid runs). This and show_* are Python methods so that
        tests can watch or stand in for the user: RNA functions such as test_break cannot be
        replaced on the class."""
        return self.test_break()

    def fail(self, message):
        """Tell the user: the report (status bar, Info editor), the render window, the console."""
        print(f"photongrid: {message}")
        self.report({"ERROR"}, message)
        if hasattr(self, "error_set"):
            self.error_set(message)
        self.update_stats("", f"photongrid: {message}")


# --------------------------------------------------------------------------------------
# The panel


class RENDER_PT_photongrid(bpy.types.Panel):
    bl_label = "photongrid"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.photongrid
        col = layout.column()
        col.prop(props, "photons")
        col.prop(props, "neighbours")
        col.prop(props, "spp")
        col.prop(props, "seed")
        col.prop(props, "direct")
        col = layout.column(heading="Future Methods")
        col.prop(props, "method")
        col.prop(props, "grid")
        col.prop(props, "time_budget")
        try:
            core.find_binary(configured_binary())
        except core.PhotongridError as e:
            box = layout.box()
            box.alert = True
            box.label(text=str(e), icon="ERROR")


# Blender's own panels (output, color management, camera, object ...) list the engines they are
# shown for; photongrid joins those of Blender's internal engines (as Blender's RenderEngine
# template does), plus EEVEE's light and material panels for light power and the material's
# node tree, which the exported glTF takes.
_EEVEE_PANELS = {
    "DATA_PT_EEVEE_light",
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
}
_EXCLUDED_PANELS = {"VIEWLAYER_PT_filter", "VIEWLAYER_PT_layer_passes"}
_patched_panels = []


def _compatible_panels():
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if not isinstance(engines, set) or panel.__name__ in _EXCLUDED_PANELS:
            continue
        if "BLENDER_RENDER" in engines or panel.__name__ in _EEVEE_PANELS:
            yield panel


classes = (
    PhotongridPreferences,
    PhotongridSceneSettings,
    PhotongridRenderEngine,
    RENDER_PT_photongrid,
)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.photongrid = PointerProperty(type=PhotongridSceneSettings)
    for panel in _compatible_panels():
        if ENGINE_ID not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add(ENGINE_ID)
            _patched_panels.append(panel)


def unregister():
    for panel in _patched_panels:
        panel.COMPAT_ENGINES.discard(ENGINE_ID)
    _patched_panels.clear()
    del bpy.types.Scene.photongrid
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
