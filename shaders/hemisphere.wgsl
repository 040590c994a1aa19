// Equal-angle hemisphere rasterisation (DESIGN.md section 2).
//
// Per shot: `bounds` (compute) finds, for every rasterisation proxy (an element
// or a piece of one), a conservative rectangle in (theta, phi) cell space that
// contains its projection onto the shooter's hemisphere. `vs` draws that
// rectangle (twice: the second copy shifted by -2 pi, for proxies that cross the
// theta = 0 seam), and `fs` tests the cell-centre ray exactly against the
// proxy's planar quad in 3-D. Straight edges curve under the equal-angle map, so
// exact per-cell testing, not tessellation, is what makes the projection right.
// Depth is the distance along the ray; back faces write BLOCKED (they stop light
// but receive none).

const PI: f32 = 3.14159265358979;
const TWO_PI: f32 = 6.28318530717959;
const HALF_PI: f32 = 1.57079632679490;
const BLOCKED: u32 = 0xfffffffeu;
// Rectangles grow by this many cells to absorb rounding.
const MARGIN: f32 = 0.01;

struct Shot {
    centre: vec4<f32>,     // xyz: hemisphere centre; w: far distance (depth = t / far)
    tangent: vec4<f32>,    // theta = 0
    bitangent: vec4<f32>,  // theta = pi / 2
    normal: vec4<f32>,     // phi = 0
    res: vec4<u32>,        // rows (R_phi), cols (R_theta), shooter polygon, proxy count
    tiles: vec4<u32>,      // tile width, tile height, ranks along theta (px), along phi (py)
    own: vec4<u32>,        // this rank's grid coordinates (x, y)
}

struct Proxy {
    c: array<vec4<f32>, 4>, // corners, counter-clockwise about n (a triangle repeats c[2])
    n: vec3<f32>,           // front normal of the polygon
    polygon: u32,
    element: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> shot: Shot;
@group(0) @binding(1) var<storage, read> proxies: array<Proxy>;
@group(0) @binding(2) var<storage, read_write> rects_out: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> rects_in: array<vec4<f32>>;

fn to_local(p: vec3<f32>) -> vec3<f32> {
    let d = p - shot.centre.xyz;
    return vec3<f32>(dot(d, shot.tangent.xyz), dot(d, shot.bitangent.xyz), dot(d, shot.normal.xyz));
}

fn wrap_angle(a: f32) -> f32 {
    return a - TWO_PI * floor(a / TWO_PI);
}

@compute @workgroup_size(64)
fn bounds(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * 65535u * 64u;
    if (i >= shot.res.w) {
        return;
    }
    let empty = vec4<f32>(1.0, 0.0, 1.0, 0.0);
    let p = proxies[i];
    if (p.polygon == shot.res.z) {
        rects_out[i] = empty; // the shooter's own polygon
        return;
    }
    let rows = f32(shot.res.x);
    let cols = f32(shot.res.y);
    let far = shot.centre.w;
    var u: array<vec3<f32>, 4>;
    var zmax = -1.0e30;
    var near_origin = false;
    for (var k = 0u; k < 4u; k++) {
        let d = to_local(p.c[k].xyz);
        zmax = max(zmax, d.z);
        let len = length(d);
        if (len < 1.0e-7 * far) {
            near_origin = true;
            u[k] = vec3<f32>(0.0, 0.0, 1.0);
        } else {
            u[k] = d / len;
        }
    }
    // Entirely on or below the shooter's tangent plane (coplanar neighbours too).
    if (zmax <= 1.0e-6 * far) {
        rects_out[i] = empty;
        return;
    }
    if (near_origin) {
        rects_out[i] = vec4<f32>(0.0, cols, 0.0, rows);
        return;
    }
    // Azimuth: the smallest arc holding every corner. A convex proxy that holds
    // neither pole spans less than pi; otherwise take every column.
    var full = false;
    var a: array<f32, 4>;
    for (var k = 0u; k < 4u; k++) {
        let r = length(u[k].xy);
        if (r < 1.0e-6) {
            full = true;
        }
        a[k] = wrap_angle(atan2(u[k].y, u[k].x));
    }
    var t0 = 0.0;
    var span = TWO_PI;
    for (var k = 0u; k < 4u; k++) {
        var s = 0.0;
        for (var j = 0u; j < 4u; j++) {
            s = max(s, wrap_angle(a[j] - a[k]));
        }
        if (s < span) {
            span = s;
            t0 = a[k];
        }
    }
    if (span >= 0.999 * PI) {
        full = true;
    }
    // Polar angle: the largest is at a corner (or the horizon); the smallest at
    // a corner or inside an edge's great-circle arc.
    var phi_max = 0.0;
    var phi_min = HALF_PI;
    for (var k = 0u; k < 4u; k++) {
        let ph = acos(clamp(u[k].z, -1.0, 1.0));
        phi_max = max(phi_max, ph);
        phi_min = min(phi_min, ph);
        let b = u[(k + 1u) % 4u];
        let m = cross(u[k], b);
        let ml = length(m);
        if (ml > 1.0e-9) {
            let mh = m / ml;
            let q = vec3<f32>(0.0, 0.0, 1.0) - mh.z * mh;
            let ql = length(q);
            if (ql > 1.0e-9) {
                let top = q / ql;
                if (dot(cross(u[k], top), mh) >= 0.0 && dot(cross(top, b), mh) >= 0.0) {
                    phi_min = min(phi_min, acos(clamp(top.z, -1.0, 1.0)));
                }
            }
        }
    }
    phi_max = min(phi_max, HALF_PI);
    if (full) {
        rects_out[i] = vec4<f32>(0.0, cols, 0.0, phi_max / HALF_PI * rows + MARGIN);
        return;
    }
    let x0 = t0 / TWO_PI * cols - MARGIN;
    let x1 = (t0 + span) / TWO_PI * cols + MARGIN;
    rects_out[i] = vec4<f32>(x0, x1, phi_min / HALF_PI * rows - MARGIN, phi_max / HALF_PI * rows + MARGIN);
}

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) @interpolate(flat) proxy: u32,
}

@vertex
fn vs(@builtin(vertex_index) vi: u32) -> VsOut {
    let i = vi / 12u;
    let k = vi % 12u;
    let copy = k / 6u;
    let corner = k % 6u;
    let r = rects_in[i];
    var out: VsOut;
    out.proxy = i;
    if (r.x > r.y) {
        out.pos = vec4<f32>(-2.0, -2.0, 0.5, 1.0); // empty: degenerate, clipped away
        return out;
    }
    // Two triangles: (0,0) (1,0) (0,1) and (0,1) (1,0) (1,1).
    var cx = 0.0;
    var cy = 0.0;
    if (corner == 1u || corner == 4u || corner == 5u) { cx = 1.0; }
    if (corner == 2u || corner == 3u || corner == 5u) { cy = 1.0; }
    let cols = f32(shot.res.y);
    let rows = f32(shot.res.x);
    let x = mix(r.x, r.y, cx) - f32(copy) * cols;
    let y = mix(r.z, r.w, cy);
    out.pos = vec4<f32>(x / cols * 2.0 - 1.0, 1.0 - y / rows * 2.0, 0.5, 1.0);
    return out;
}

// Distance along `dir` from `o` to the proxy, or -1 when the ray misses it.
fn intersect(p: Proxy, o: vec3<f32>, dir: vec3<f32>) -> f32 {
    let denom = dot(p.n, dir);
    if (abs(denom) < 1.0e-12) {
        return -1.0;
    }
    let t = dot(p.n, p.c[0].xyz - o) / denom;
    if (t <= 0.0) {
        return -1.0;
    }
    let hit = o + t * dir;
    // Edge tolerance: a millionth of the distance, far below a cell's footprint,
    // so shared edges leave no cracks (ties go to the first proxy drawn).
    let tol = 1.0e-6 * t;
    for (var k = 0u; k < 4u; k++) {
        let a = p.c[k].xyz;
        let e = p.c[(k + 1u) % 4u].xyz - a;
        if (dot(cross(e, hit - a), p.n) < -tol * length(e)) {
            return -1.0;
        }
    }
    return t;
}

struct FsOut {
    @location(0) item: u32,
    @builtin(frag_depth) depth: f32,
}

@fragment
fn fs(in: VsOut) -> FsOut {
    let cell = vec2<u32>(in.pos.xy);
    let owner = vec2<u32>((cell.x / shot.tiles.x) % shot.tiles.z, (cell.y / shot.tiles.y) % shot.tiles.w);
    if (any(owner != shot.own.xy)) {
        discard;
    }
    let theta = in.pos.x * TWO_PI / f32(shot.res.y);
    let phi = in.pos.y * HALF_PI / f32(shot.res.x);
    let sp = sin(phi);
    let dir = sp * cos(theta) * shot.tangent.xyz + sp * sin(theta) * shot.bitangent.xyz + cos(phi) * shot.normal.xyz;
    let p = proxies[in.proxy];
    let t = intersect(p, shot.centre.xyz, dir);
    let far = shot.centre.w;
    if (t <= 1.0e-6 * far) {
        discard;
    }
    var out: FsOut;
    let back = dot(p.n, shot.centre.xyz - p.c[0].xyz) <= 0.0;
    if (back) {
        // Just behind a coincident front face, so the front wins the tie.
        out.item = BLOCKED;
        out.depth = min(t / far * (1.0 + 1.0e-5), 1.0);
    } else {
        out.item = p.element;
        out.depth = min(t / far, 1.0);
    }
    return out;
}
