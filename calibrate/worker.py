"""Blender/Cycles render worker — runs inside ``.venv-blender`` (bpy + numpy only).

    python calibrate/worker.py JOB_DIR

reads ``JOB_DIR/job.json`` and ``JOB_DIR/arrays.npz`` (written by
:mod:`calibrate.job`), renders one image per frame with Cycles and writes
``JOB_DIR/result.npz`` (``pixel_sum`` per frame, ``seconds`` per frame) and
``result.json``. Progress goes to stdout as ``FRAME i n seconds`` lines; errors
to stderr with a non-zero exit status.

The scene is built in a frame centred on the object (GCRS positions in float32
would lose millimetres): the object sits at the origin with the body → inertial
rotation of each frame (keyframed over the exposure for motion blur), the Sun
lamp shines along −s, the camera looks along −v. Sun strength is the
irradiance in W/m² (point Sun, angle 0), the world is black, denoising off,
EXR 32-bit grey-scale: pixel values are radiance in W m⁻² sr⁻¹.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time

#: The job format this worker reads (``calibrate.job.JOB_VERSION`` writes it).
JOB_VERSION = 2


def _fail(message: str, code: int = 2):
    print(f"worker error: {message}", file=sys.stderr, flush=True)
    sys.exit(code)


try:
    import bpy
    import numpy as np
    from mathutils import Quaternion, Vector
except ImportError as exc:  # wrong interpreter: say so plainly
    _fail(f"this worker needs bpy and numpy (the .venv-blender environment): {exc}")


def _look_rotation(direction) -> Quaternion:
    """Rotation that points an object's local −Z along ``direction`` (camera/lamp)."""
    d = Vector(direction).normalized()
    return d.to_track_quat("-Z", "Y")


def _material(spec: dict) -> bpy.types.Material:
    """Cycles material for a jaxlc BRDF (see calibrate.job.material_spec)."""
    mat = bpy.data.materials.new(spec["part"])
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*([spec["diffuse"]] * 3), 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0  # Lambert
    if spec.get("glossy", 0.0) <= 0.0:
        nt.links.new(diffuse.outputs[0], out.inputs["Surface"])
        return mat
    glossy = nt.nodes.new("ShaderNodeBsdfAnisotropic")  # "Glossy BSDF" in Blender 5
    glossy.distribution = "ASHIKHMIN_SHIRLEY"
    glossy.inputs["Color"].default_value = (*([spec["glossy"]] * 3), 1.0)
    glossy.inputs["Roughness"].default_value = spec["roughness"]
    glossy.inputs["Anisotropy"].default_value = spec.get("anisotropy", 0.0)
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(diffuse.outputs[0], add.inputs[0])
    nt.links.new(glossy.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Surface"])
    return mat


#: Face attribute holding each triangle's mesh index + 1 (visibility renders).
TRIANGLE_ATTRIBUTE = "jaxlc_triangle"
#: Name of the node that switches a visibility material between its two renders.
MODE_NODE = "jaxlc_mode"


def _visibility_material(name: str) -> bpy.types.Material:
    """White Lambert (mode 0: is the point sunlit?) or an emission of the triangle's
    index + 1 (mode 1: which triangle is seen?), switched by the MODE_NODE mix."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = TRIANGLE_ATTRIBUTE
    emission = nt.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    nt.links.new(attr.outputs["Fac"], emission.inputs["Strength"])
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.name = MODE_NODE
    nt.links.new(diffuse.outputs[0], mix.inputs[1])
    nt.links.new(emission.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def _set_mode(value: float) -> None:
    for mat in bpy.data.materials:
        if mat.node_tree is not None and MODE_NODE in mat.node_tree.nodes:
            mat.node_tree.nodes[MODE_NODE].inputs[0].default_value = value


def build_scene(job: dict, arrays) -> tuple:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    r = job["render"]
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.samples = int(r["samples"])
    cyc.use_adaptive_sampling = False
    cyc.use_denoising = False
    cyc.seed = int(r.get("seed", 0))
    cyc.max_bounces = int(r["bounces"])
    cyc.diffuse_bounces = cyc.glossy_bounces = int(r["bounces"])
    cyc.transparent_max_bounces = 0
    cyc.film_exposure = 1.0
    scene.render.threads_mode = "FIXED" if r.get("threads") else "AUTO"
    if r.get("threads"):
        scene.render.threads = int(r["threads"])
    scene.render.resolution_x = scene.render.resolution_y = int(r["resolution"])
    scene.render.resolution_percentage = 100
    fmt = scene.render.image_settings
    fmt.file_format = "OPEN_EXR"
    fmt.color_depth = "32"
    fmt.color_mode = "BW"
    scene.render.use_motion_blur = bool(r.get("motion_blur"))
    scene.render.fps = int(r.get("fps", 1000))
    scene.render.fps_base = 1.0

    world = bpy.data.worlds.new("black")
    scene.world = world
    bg = world.node_tree.nodes.get("Background") if world.node_tree else None
    if bg is not None:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0

    visibility = bool(job.get("visibility"))
    if visibility:  # one ray through each pixel's centre: nothing averaged
        cyc.pixel_filter_type = "BOX"
        cyc.filter_width = 0.01
    obj = bpy.data.objects.new("object", None)
    obj.rotation_mode = "QUATERNION"
    scene.collection.objects.link(obj)
    make = (lambda m: _visibility_material(m["part"])) if visibility else _material
    materials = {m["part"]: make(m) for m in job["materials"]}
    for k, part in enumerate(job["parts"]):
        mesh = bpy.data.meshes.new(part)
        verts = arrays[f"vertices_{k}"].tolist()
        faces = arrays[f"faces_{k}"].tolist()
        mesh.from_pydata(verts, [], faces)
        mesh.validate()
        mesh.update()
        if visibility:
            ids = arrays[f"triangle_ids_{k}"]
            if len(mesh.polygons) != len(ids):
                _fail(
                    f"part {part!r}: Blender kept {len(mesh.polygons)} of {len(ids)} triangles; "
                    "a visibility render needs every triangle (drop degenerate ones first)"
                )
            attr = mesh.attributes.new(name=TRIANGLE_ATTRIBUTE, type="FLOAT", domain="FACE")
            attr.data.foreach_set("value", (np.asarray(ids) + 1.0).astype(np.float32))
        mesh.materials.append(materials[part])
        child = bpy.data.objects.new(part, mesh)
        scene.collection.objects.link(child)
        child.parent = obj
        child.cycles.motion_steps = int(r.get("motion_steps", 1))
    obj.cycles.motion_steps = int(r.get("motion_steps", 1))

    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.angle = 0.0
    if r.get("blackbody"):
        sun_data.use_nodes = True
        nodes = sun_data.node_tree.nodes
        blackbody = nodes.new("ShaderNodeBlackbody")
        blackbody.inputs["Temperature"].default_value = 5778.0
        sun_data.node_tree.links.new(blackbody.outputs[0], nodes["Emission"].inputs["Color"])
    sun = bpy.data.objects.new("sun", sun_data)
    scene.collection.objects.link(sun)

    cam_data = bpy.data.cameras.new("camera")
    cam = job["camera"]
    if cam["mode"] == "ortho":
        cam_data.type = "ORTHO"
    else:
        cam_data.type = "PERSP"
        cam_data.sensor_fit = "HORIZONTAL"
    cam_data.clip_start = float(cam.get("clip_start", 1e-3))
    cam_data.clip_end = float(cam.get("clip_end", 1e9))
    camera = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    return scene, obj, sun, camera


def render_frames(job: dict, arrays, out_dir: str) -> tuple:
    scene, obj, sun, camera = build_scene(job, arrays)
    n = len(arrays["sun_dir"])
    quats = arrays["quaternions"]  # (n, K, 4): keyframes over each exposure
    keys = quats.shape[1]
    cam = job["camera"]
    sums = np.zeros(n)
    seconds = np.zeros(n)
    keep = job.get("keep_images", False)
    visibility = None
    if job.get("visibility"):
        n_tri = int(job["triangles"])
        visibility = {
            "seen_pixels": np.zeros((n, n_tri), np.int32),
            "lit_pixels": np.zeros((n, n_tri), np.int32),
        }
    for i in range(n):
        t0 = time.perf_counter()
        obj.animation_data_clear()
        for k in range(keys):  # one keyframe per sub-exposure instant, linear in between
            obj.rotation_quaternion = Quaternion(quats[i, k].tolist())
            obj.keyframe_insert("rotation_quaternion", frame=1 + k)
        if obj.animation_data and obj.animation_data.action:
            for fcurve in _fcurves(obj.animation_data.action):
                for point in fcurve.keyframe_points:
                    point.interpolation = "LINEAR"
        centre = 1 + (keys - 1) / 2.0
        scene.frame_set(math.floor(centre), subframe=centre - math.floor(centre))
        scene.render.motion_blur_shutter = float(keys - 1) if keys > 1 else 0.5
        scene.render.use_motion_blur = bool(job["render"].get("motion_blur")) and keys > 1

        sun.data.energy = float(arrays["irradiance_w_m2"][i])
        sun.rotation_mode = "QUATERNION"
        sun.rotation_quaternion = _look_rotation((-arrays["sun_dir"][i]).tolist())
        view = arrays["obs_dir"][i]
        camera.rotation_mode = "QUATERNION"
        camera.rotation_quaternion = _look_rotation((-view).tolist())
        camera.location = (view * float(arrays["camera_distance"][i])).tolist()
        if cam["mode"] == "ortho":
            camera.data.ortho_scale = float(cam["ortho_scale"])
        else:
            camera.data.angle = float(arrays["fov_rad"][i])

        if visibility is not None:
            _set_mode(1.0)
            seen = np.rint(_render_image(scene, out_dir, i, "id", keep)).astype(np.int64) - 1
            _set_mode(0.0)
            lit = _render_image(scene, out_dir, i, "lit", keep) > 0.0
            hit = seen >= 0
            n_tri = visibility["seen_pixels"].shape[1]
            visibility["seen_pixels"][i] = np.bincount(seen[hit], minlength=n_tri)[:n_tri]
            visibility["lit_pixels"][i] = np.bincount(seen[hit & lit], minlength=n_tri)[:n_tri]
            sums[i] = float(hit.sum())
        else:
            sums[i] = float(
                _render_image(scene, out_dir, i, "frame", keep).astype(np.float64).sum()
            )
        seconds[i] = time.perf_counter() - t0
        print(f"FRAME {i + 1} {n} {seconds[i]:.3f}", flush=True)
    return sums, seconds, visibility or {}


def _render_image(scene, out_dir: str, i: int, what: str, keep: bool) -> np.ndarray:
    """Render the current frame and return its first channel (H·W,) as float32."""
    path = os.path.join(out_dir, f"{what}_{i:05d}.exr")
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(path)
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    channels = image.channels
    bpy.data.images.remove(image)
    if not keep:
        os.remove(path)
    return pixels.reshape(-1, channels)[:, 0]


def _fcurves(action):
    """F-curves of an action (Blender 5 keeps them in layered channel bags)."""
    if hasattr(action, "fcurves") and len(getattr(action, "fcurves", [])):
        return list(action.fcurves)
    curves = []
    for layer in getattr(action, "layers", []):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", []):
                curves.extend(bag.fcurves)
    return curves


def check_job(job: dict, arrays: dict) -> None:
    """Refuse a job of another format version, or with missing or misshapen arrays."""
    version = job.get("version")
    if version != JOB_VERSION:
        _fail(
            f"job format version {version!r}, this worker reads version {JOB_VERSION}; "
            "the main environment and .venv-blender hold different jaxlc checkouts"
        )
    for key in ("parts", "materials", "camera", "render"):
        if key not in job:
            _fail(f"job.json has no {key!r}")
    n = len(arrays.get("sun_dir", ()))
    shapes = {
        "quaternions": (n, None, 4),
        "sun_dir": (n, 3),
        "obs_dir": (n, 3),
        "irradiance_w_m2": (n,),
        "camera_distance": (n,),
    }
    if job["camera"].get("mode") != "ortho":
        shapes["fov_rad"] = (n,)
    for k in range(len(job["parts"])):
        shapes[f"vertices_{k}"] = (None, 3)
        shapes[f"faces_{k}"] = (None, 3)
    for key, shape in shapes.items():
        a = arrays.get(key)
        ok = a is not None and a.ndim == len(shape)
        ok = ok and all(s is None or s == d for s, d in zip(shape, a.shape, strict=True))
        if not ok:
            got = "missing" if a is None else f"shape {a.shape}"
            _fail(f"job array {key!r} is {got}, expected {shape} (None: any)")
    names = {m["part"] for m in job["materials"]}
    missing = [p for p in job["parts"] if p not in names]
    if missing:
        _fail(f"job part {missing[0]!r} has no material")


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        _fail("usage: worker.py JOB_DIR")
    job_dir = argv[0]
    try:
        with open(os.path.join(job_dir, "job.json"), encoding="utf-8") as fh:
            job = json.load(fh)
        arrays = dict(np.load(os.path.join(job_dir, "arrays.npz")))
    except (OSError, ValueError) as exc:
        _fail(f"cannot read the job in {job_dir}: {exc}")
    if job.get("crash_for_test"):
        _fail("crash requested by the job (test of the failure path)", code=3)
    if job.get("hang_for_test"):
        time.sleep(3600)
    check_job(job, arrays)
    images = job.get("image_dir") or os.path.join(job_dir, "images")
    os.makedirs(images, exist_ok=True)
    sums, seconds, counts = render_frames(job, arrays, images)
    tmp = os.path.join(job_dir, "result.tmp.npz")
    np.savez(tmp, pixel_sum=sums, seconds=seconds, **counts)
    os.replace(tmp, os.path.join(job_dir, "result.npz"))
    with open(os.path.join(job_dir, "result.json"), "w", encoding="utf-8") as fh:
        json.dump({"frames": len(sums), "blender": bpy.app.version_string}, fh)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
