# SPDX-License-Identifier: GPL-3.0-or-later
"""photongrid render engine for Blender 4.2+ (an extension; also Blender 5.x).

F12 exports the scene with Blender's glTF exporter, runs the ``photongrid`` binary (the one the
extension carries, unless the preferences or ``PHOTONGRID_BIN`` name another) for the active
camera and loads its EXR into the render result: the image after every pass as it refines,
then the passes (Depth, Normal, Diffuse Color, photon density and radius) the view layer asks
for. Esc ends the render after the current pass and keeps it.

The panel's settings are built from the binary's own description of them
(``photongrid settings --schema``): names, defaults, choices and tooltips are never copied here.
The work is done by ``core`` (plain Python); this module is the Blender glue.
"""

import os
import shutil
import tempfile
import traceback

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import core

ENGINE_ID = "PHOTONGRID"


# --------------------------------------------------------------------------------------
# Preferences


def _binary_changed(_self, _context):
    # Another binary may have other settings: rebuild the panel's properties from its schema.
    try:
        register_scene_settings()
    except Exception:  # noqa: BLE001 - a preference edit must not raise into the UI
        traceback.print_exc()


class PhotongridPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    binary_path: StringProperty(
        name="photongrid Binary",
        description=(
            "Path of a photongrid executable to use instead of the one the add-on carries. Empty: "
            "the PHOTONGRID_BIN environment variable, then the add-on's own, then photongrid on PATH"
        ),
        subtype="FILE_PATH",
        default="",
        update=_binary_changed,
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
    (e.g. ``register()`` called from a script or test): then env, the bundled binary and PATH
    are used."""
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


def _cache_dir():
    """Where the settings schema of a binary is cached between sessions."""
    try:
        return bpy.utils.extension_path_user(__package__, path="cache", create=True)
    except Exception:  # noqa: BLE001 - not installed as an extension (tests, scripts)
        return os.path.join(tempfile.gettempdir(), "photongrid-cache")


# --------------------------------------------------------------------------------------
# Scene settings, built from the binary's schema

_state = {"schema": core.EMPTY_SCHEMA, "specs": [], "source": "", "error": "", "class": None}


def current_schema():
    """The schema of the binary in use (run once per binary, then cached), else the one the
    extension carries; (schema, where it came from, why the binary's could not be read)."""
    error = ""
    try:
        binary = core.find_binary(configured_binary())
        try:
            return core.schema_from_binary(binary, _cache_dir()), binary, ""
        except core.PhotongridError as e:
            error = str(e)
    except core.PhotongridError as e:
        error = str(e)
    bundled = core.bundled_schema()
    if bundled is not None:
        return bundled, core.BUNDLED_SCHEMA, error
    return core.EMPTY_SCHEMA, "", error


def _blender_property(spec):
    common = dict(name=spec.label, description=spec.description)
    if spec.kind == "INT":
        return IntProperty(default=int(spec.default), min=0, **common)
    if spec.kind == "FLOAT":
        return FloatProperty(default=float(spec.default), min=0.0, precision=3, **common)
    if spec.kind == "BOOL":
        return BoolProperty(default=bool(spec.default), **common)
    if spec.kind == "ENUM":
        ids = [i[0] for i in spec.items]
        default = spec.default if spec.default in ids else ids[0]
        return EnumProperty(items=spec.items, default=default, **common)
    return StringProperty(default=str(spec.default), **common)


def _defaults():
    return {sp.key: sp.default for sp in _state["specs"]}


def _quality_get(self):
    defaults = _defaults()
    for i, (name, _label, _desc) in enumerate(core.QUALITY_PRESETS):
        values = core.quality_values(name, defaults)
        if values and all(core.same_value(getattr(self, k, None), v) for k, v in values.items()):
            return i
    return len(core.QUALITY_PRESETS)  # Custom


def _quality_set(self, index):
    if index >= len(core.QUALITY_PRESETS):
        return
    for key, value in core.quality_values(core.QUALITY_PRESETS[index][0], _defaults()).items():
        if hasattr(self, key):
            setattr(self, key, value)


def register_scene_settings():
    """(Re)build ``Scene.photongrid`` from the current binary's schema. Values already in the
    .blend are kept: they are stored by name."""
    schema, source, error = current_schema()
    specs = core.property_specs(schema)
    annotations = {sp.key: _blender_property(sp) for sp in specs}
    annotations["quality"] = EnumProperty(
        name="Quality",
        description="Photons, caustic photons, samples and gather rays per pass as a preset (Custom: as set below)",
        items=[*core.QUALITY_PRESETS, ("CUSTOM", "Custom", "Values set by hand")],
        get=_quality_get,
        set=_quality_set,
    )
    annotations["passes"] = IntProperty(
        name="Passes",
        description=(core.schema_help(schema, "passes") + " 0: as many as the time limit allows.").strip(),
        default=1,
        min=0,
        soft_max=1000,
    )
    annotations["time_limit"] = FloatProperty(
        name="Time Limit",
        description=(core.schema_help(schema, "time") + " 0: no limit.").strip(),
        default=0.0,
        min=0.0,
        step=100,
        unit="TIME_ABSOLUTE",
    )
    cls = type("PhotongridSceneSettings", (bpy.types.PropertyGroup,), {"__annotations__": annotations})
    old = _state["class"]
    if old is not None:
        del bpy.types.Scene.photongrid
        bpy.utils.unregister_class(old)
    bpy.utils.register_class(cls)
    bpy.types.Scene.photongrid = PointerProperty(type=cls)
    _state.update(schema=schema, specs=specs, source=source, error=error, **{"class": cls})
    return cls


def unregister_scene_settings():
    cls = _state["class"]
    if cls is not None:
        del bpy.types.Scene.photongrid
        bpy.utils.unregister_class(cls)
        _state["class"] = None


class PhotongridViewLayerSettings(bpy.types.PropertyGroup):
    use_pass_photon_density: BoolProperty(
        name="Photon Density",
        description="Photons per m² at the first diffuse surface the camera sees (pass \"Photon Density\")",
        default=False,
    )
    use_pass_photon_radius: BoolProperty(
        name="Photon Radius",
        description="Radius in m of the photon estimate at the first diffuse surface (pass \"Photon Radius\")",
        default=False,
    )


def _pass_enabled(view_layer, switch):
    if hasattr(view_layer, switch):
        return bool(getattr(view_layer, switch))
    own = getattr(view_layer, "photongrid", None)
    return bool(getattr(own, switch, False))


def enabled_passes(view_layer):
    """The Blender passes (name, channel ids, type) this view layer asks for, besides Combined."""
    return [(name, ids, kind) for name, ids, kind, _exr, switch in core.PASSES if _pass_enabled(view_layer, switch)]


# --------------------------------------------------------------------------------------
# The engine


class PhotongridRenderEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "photongrid"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_eevee_viewport = True

    def update_render_passes(self, scene=None, renderlayer=None):
        """The passes of the view layer (View Layer > Passes), for the result and the compositor."""
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
        for name, ids, kind in enabled_passes(renderlayer):
            self.register_pass(scene, renderlayer, name, len(ids), ids, kind)

    def render(self, depsgraph):
        if self.is_preview:
            return
        scene = depsgraph.scene
        width, height = self.resolution_x, self.resolution_y
        if width <= 0 or height <= 0:
            width, height = core.render_size(scene)
        camera = self.camera_override or scene.camera
        self._result = None
        try:
            binary = core.find_binary(configured_binary())
            if camera is None:
                raise core.PhotongridError("the scene has no active camera: set one in Scene properties > Camera")
            self._render(depsgraph, scene, binary, camera.name, width, height)
        except core.Cancelled:
            self.update_stats("", "photongrid: cancelled")
        except core.PhotongridError as e:
            self.fail(str(e))
        except Exception as e:  # noqa: BLE001 - a bug here must not look like a finished render
            traceback.print_exc()
            self.fail(f"photongrid add-on error: {type(e).__name__}: {e}")
        finally:
            # An image already shown (a pass before Esc) stays; after a failure it is dropped.
            if self._result is not None:
                self.end_result(self._result, cancel=bool(getattr(self, "_failed", False)))
                self._result = None

    def _render(self, depsgraph, scene, binary, camera_name, width, height):
        prefs = preferences()
        keep = bool(getattr(prefs, "keep_temp_files", False))
        base = getattr(self, "temporary_directory", "") or None
        if base and not os.path.isdir(base):
            base = None
        if self.is_animation:
            # Ctrl+F12 advances the scene's frame without re-evaluating the depsgraph that the
            # glTF exporter reads: without this every frame would export the first one.
            scene.frame_set(scene.frame_current, subframe=scene.frame_subframe)
        view_layer = depsgraph.view_layer
        passes = enabled_passes(view_layer)
        self._layer = view_layer.name
        self._transparent = bool(scene.render.film_transparent)
        specs = _state["specs"]
        settings = core.settings_from_scene(scene, specs, aovs=bool(passes))
        phases = core.expected_phases(settings.values, _defaults())
        workdir = tempfile.mkdtemp(prefix="photongrid-", dir=base)
        try:
            run = core.run_photongrid(
                scene,
                workdir,
                binary,
                settings=settings,
                camera=camera_name,
                size=(width, height),
                on_status=self.show_status,
                on_progress=self.show_progress,
                should_cancel=self.cancel_requested,
                on_checkpoint=lambda path, n: self.show_image(path, width, height, passes, n),
                on_warning=self.show_warning,
                phases=phases,
            )
            self.update_stats("", "photongrid: loading image")
            self.show_image(run.path, width, height, passes, run.passes, final=True)
            self.show_progress(1.0)
            done = "stopped after" if run.stopped else "done,"
            n = f" {run.passes} pass{'' if run.passes == 1 else 'es'}" if run.passes else ""
            self.update_stats("", f"photongrid: {done}{n}")
        finally:
            if keep:
                print(f"photongrid: temporary files kept in {workdir}")
            else:
                shutil.rmtree(workdir, ignore_errors=True)

    def show_image(self, path, width, height, passes, count=None, final=False):
        """Put the EXR at ``path`` into the render result: Combined always, the view layer's
        passes when the file has them. Called after every pass (progressive display) and at the
        end; a Python method so that tests can watch it."""
        channels = core.read_exr_channels(path, width, height)
        import numpy as np

        rgba = np.ones((height, width, 4), dtype=np.float32)
        for i, c in enumerate("RGB"):
            if c not in channels:
                raise core.PhotongridError(f"{path} has no channel {c} (channels: {', '.join(channels)})")
            rgba[..., i] = channels[c]
        if self._transparent and "A" in channels:
            rgba[..., 3] = channels["A"]
        if self._result is None:
            self._result = self.begin_result(0, 0, width, height, layer=self._layer)
        # photongrid renders the whole scene: the layer being rendered gets its image.
        for layer in self._result.layers:
            layer.passes["Combined"].rect.foreach_set(rgba.ravel())
            for name, _ids, _kind in passes:
                target = layer.passes.find_by_name(name, "")
                pixels = core.pass_pixels(channels, name)
                if target is not None and pixels is not None:
                    target.rect.foreach_set(pixels)
        self.update_result(self._result)
        if not final and count:
            self.update_stats("", f"photongrid: pass {count} shown")

    def show_status(self, text):
        """The phase, in the render window's header and the status bar."""
        self.update_stats("", text)

    def show_progress(self, fraction):
        self.update_progress(fraction)

    def show_warning(self, message):
        """A warning of the renderer (an approximated material, ...) in the report: the status
        bar and the Info editor."""
        print(f"photongrid: warning: {message}")
        self.report({"WARNING"}, f"photongrid: {message}")

    def cancel_requested(self):
        """Esc pressed (polled while photongrid runs). This and show_* are Python methods so that
        tests can watch or stand in for the user: RNA functions such as test_break cannot be
        replaced on the class."""
        return self.test_break()

    def fail(self, message):
        """Tell the user: the report (status bar, Info editor), the render window, the console."""
        self._failed = True
        print(f"photongrid: {message}")
        self.report({"ERROR"}, message)
        if hasattr(self, "error_set"):
            self.error_set(message)
        self.update_stats("", f"photongrid: {message}")


# --------------------------------------------------------------------------------------
# The panels: Render Properties as Cycles lays them out, View Layer > Passes


class PhotongridPanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw_settings(self, context, keys):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.photongrid
        col = layout.column()
        for key in keys:
            if hasattr(props, key):
                col.prop(props, key)
        return col


class RENDER_PT_photongrid(PhotongridPanel, bpy.types.Panel):
    """The engine's own settings; the subpanels hold them."""

    bl_label = "photongrid"

    def draw(self, context):
        layout = self.layout
        try:
            core.find_binary(configured_binary())
        except core.PhotongridError as e:
            box = layout.box()
            box.alert = True
            box.label(text=str(e), icon="ERROR")
        if _state["error"] and not _state["specs"]:
            layout.label(text=f"settings unavailable: {_state['error']}", icon="ERROR")


class RENDER_PT_photongrid_sampling(PhotongridPanel, bpy.types.Panel):
    bl_label = "Sampling"
    bl_parent_id = "RENDER_PT_photongrid"

    def draw(self, context):
        col = self.draw_settings(context, ("quality", "time_limit", "passes"))
        props = context.scene.photongrid
        if getattr(props, "time_limit", 0) <= 0 and getattr(props, "passes", 1) == 0:
            col.label(text="No time limit: one pass", icon="INFO")
        self.draw_settings(context, core.SECTIONS["SAMPLING"])


class RENDER_PT_photongrid_photons(PhotongridPanel, bpy.types.Panel):
    bl_label = "Photons"
    bl_parent_id = "RENDER_PT_photongrid"

    def draw(self, context):
        self.draw_settings(context, core.SECTIONS["PHOTONS"])


class RENDER_PT_photongrid_light_paths(PhotongridPanel, bpy.types.Panel):
    bl_label = "Light Paths"
    bl_parent_id = "RENDER_PT_photongrid"

    def draw(self, context):
        self.draw_settings(context, core.SECTIONS["LIGHT_PATHS"])


class RENDER_PT_photongrid_method(PhotongridPanel, bpy.types.Panel):
    bl_label = "Method"
    bl_parent_id = "RENDER_PT_photongrid"

    def draw(self, context):
        col = self.draw_settings(context, ("method",))
        props = context.scene.photongrid
        sub = col.column()
        # The grid mode matters to the adaptive estimate only.
        sub.active = getattr(props, "method", "adaptive") == "adaptive"
        if hasattr(props, "grid"):
            sub.prop(props, "grid")


class RENDER_PT_photongrid_advanced(PhotongridPanel, bpy.types.Panel):
    bl_label = "Advanced"
    bl_parent_id = "RENDER_PT_photongrid"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        self.draw_settings(context, [sp.key for sp in _state["specs"] if sp.section == "ADVANCED"])


class VIEWLAYER_PT_photongrid_passes(bpy.types.Panel):
    bl_label = "Data"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "view_layer"
    bl_parent_id = "VIEWLAYER_PT_layer_passes"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        view_layer = context.view_layer
        col = layout.column(heading="Include", align=True)
        col.prop(view_layer, "use_pass_combined")
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_normal")
        col.prop(view_layer, "use_pass_diffuse_color", text="Diffuse Color")
        col = layout.column(heading="Photons", align=True)
        col.prop(view_layer.photongrid, "use_pass_photon_density", text="Density")
        col.prop(view_layer.photongrid, "use_pass_photon_radius", text="Radius")


# Blender's own panels (output, color management, camera, object ...) list the engines they are
# shown for; photongrid joins those of Blender's internal engines (as Blender's RenderEngine
# template does), plus EEVEE's light and material panels for light power and the material's
# node tree, which the exported glTF takes, and the (empty) parent of the passes panels.
_EEVEE_PANELS = {
    "DATA_PT_EEVEE_light",
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "VIEWLAYER_PT_layer_passes",
}
_EXCLUDED_PANELS = {"VIEWLAYER_PT_filter"}
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
    PhotongridViewLayerSettings,
    PhotongridRenderEngine,
    RENDER_PT_photongrid,
    RENDER_PT_photongrid_sampling,
    RENDER_PT_photongrid_photons,
    RENDER_PT_photongrid_light_paths,
    RENDER_PT_photongrid_method,
    RENDER_PT_photongrid_advanced,
)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.ViewLayer.photongrid = PointerProperty(type=PhotongridViewLayerSettings)
    register_scene_settings()
    for panel in _compatible_panels():
        if ENGINE_ID not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add(ENGINE_ID)
            _patched_panels.append(panel)
    # After its parent is known to Blender.
    bpy.utils.register_class(VIEWLAYER_PT_photongrid_passes)


def unregister():
    bpy.utils.unregister_class(VIEWLAYER_PT_photongrid_passes)
    for panel in _patched_panels:
        panel.COMPAT_ENGINES.discard(ENGINE_ID)
    _patched_panels.clear()
    unregister_scene_settings()
    del bpy.types.ViewLayer.photongrid
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
