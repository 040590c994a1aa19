// Camera view of the solution: radiance per vertex, interpolated (smooth) or
// constant per element (flat). Back faces of one-sided surfaces are black,
// drawn first and a hair farther (vs_back), so where a front face coincides
// with a back face (a wall given as two one-sided faces) the side facing the
// camera shows, decided by orientation rather than by depth order.

struct Camera {
    view_proj: mat4x4<f32>,
}

@group(0) @binding(0) var<uniform> cam: Camera;

struct VsIn {
    @location(0) pos: vec3<f32>,
    @location(1) radiance: vec3<f32>,
}

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) radiance: vec3<f32>,
}

fn transform(in: VsIn) -> VsOut {
    var out: VsOut;
    out.pos = cam.view_proj * vec4<f32>(in.pos, 1.0);
    out.radiance = in.radiance;
    return out;
}

@vertex
fn vs(in: VsIn) -> VsOut {
    return transform(in);
}

@vertex
fn vs_back(in: VsIn) -> VsOut {
    var out = transform(in);
    out.pos.z = out.pos.z + 2.0e-6 * out.pos.w;
    return out;
}

@fragment
fn fs(in: VsOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    if (!front) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    return vec4<f32>(in.radiance, 1.0);
}

// Wireframe: element edges, pulled slightly towards the camera so they are
// not hidden by the faces they lie on.
@vertex
fn vs_line(in: VsIn) -> VsOut {
    var out = transform(in);
    out.pos.z = out.pos.z - 1.0e-4 * out.pos.w;
    return out;
}

@fragment
fn fs_line(in: VsOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.radiance, 1.0);
}
