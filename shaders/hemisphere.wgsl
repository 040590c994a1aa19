// Equal-angle hemisphere rasterisation (DESIGN.md section 2).
//
// Per shot the CPU finds, for every rasterisation proxy (an element or a piece
// of one) that the shooter can see, a conservative rectangle in (theta, phi)
// cell space that holds its projection (`hemisphere::cell_bounds`), with a
// second copy shifted by -2 pi for rectangles that cross the theta = 0 seam.
// Each rectangle carries its proxy in the shooter's frame: the planes through
// the hemisphere centre and each edge (unit normals, oriented inwards) and the
// proxy's own plane. `vs` draws the rectangle; `fs` tests the cell-centre ray
// exactly: inside every edge plane, then distance = plane offset / cos. Straight
// edges curve under the equal-angle map, so this exact per-cell test, not
// tessellation, is what makes the projection right. Depth is that distance;
// back faces write BLOCKED (they stop light but receive none).

const BLOCKED: u32 = 0xfffffffeu;
// Angular tolerance of the edge tests (radians): far below a cell, so shared
// edges leave no cracks. Ties go to the rectangle drawn first.
const EDGE_TOL: f32 = 1.0e-6;
// Pixels a lattice-mode rectangle grows by on each side.
const LATTICE_MARGIN: f32 = 0.02;

struct Shot {
    res: vec4<u32>,    // rows (R_phi), cols (R_theta), unused, unused
    tiles: vec4<u32>,  // tile width, tile height, ranks along theta (px), along phi (py)
    own: vec4<u32>,    // this rank's grid coordinates (x, y); z = 1: lattice mode (1 x 1 tiles);
                       // w = 1: count coverage
    depth: vec4<f32>,  // x: 1 / far (depth = distance / far)
    per_tile: vec4<f32>, // 1 / tiles.x, 1 / tiles.y, 1 / tiles.z, 1 / tiles.w (see `div_by`)
}

@group(0) @binding(0) var<uniform> shot: Shot;
// Per element: cells whose ray hits its front, hidden or not (hybrid form
// factors divide the visible cells by these, so aliasing cancels). The depth
// test runs after this shader (it writes depth), so every hit is counted.
@group(0) @binding(1) var<storage, read_write> coverage: array<atomic<u32>>;
// Cell-centre directions, computed once in f64 (`hemisphere::direction_table`):
// entry k holds row k's (sin phi, cos phi) and column k's (cos theta, sin
// theta), for up to 4096 rows and columns (64 KiB, the uniform binding
// every device offers). The driver's f32 sin/cos have unspecified
// precision; a table makes every driver see the same rays. Uniform, not
// storage: lavapipe loads storage lane by lane with bounds checks, and the
// two loads a fragment from a storage table cost 5 % of a shot.
@group(0) @binding(2) var<uniform> trig: array<vec4<f32>, 4096>;

struct Rect {
    @location(0) rect: vec4<f32>,   // x0, x1, y0, y1 in cells
    @location(1) e0: vec3<f32>,     // inward unit normals of the edge planes
    @location(2) e1: vec3<f32>,
    @location(3) e2: vec3<f32>,
    @location(4) e3: vec3<f32>,
    @location(5) plane: vec4<f32>,  // proxy plane: normal, offset (n . corner)
    @location(6) item: vec2<u32>,   // element id (first element of a quad grid), back-facing flag
    // A piece of a quad polygon: its bilinear map p = o + u e1 + v e2 + u v g
    // in a 2-D basis of its plane (x along e1, y = normal x x), for finding
    // the element at the hit point. grid = (0, ...): the piece is one element.
    @location(7) origin: vec4<f32>,   // o (shooter frame), g.y
    @location(8) axis: vec4<f32>,     // x axis (shooter frame)
    @location(9) bilinear: vec4<f32>, // |e1|, e2.x, e2.y, g.x
    @location(10) grid: vec4<u32>,    // elements along u, along v; per patch along u, along v
}

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) @interpolate(flat) e0: vec3<f32>,
    @location(1) @interpolate(flat) e1: vec3<f32>,
    @location(2) @interpolate(flat) e2: vec3<f32>,
    @location(3) @interpolate(flat) e3: vec3<f32>,
    @location(4) @interpolate(flat) plane: vec4<f32>,
    @location(5) @interpolate(flat) item: vec2<u32>,
    @location(6) @interpolate(flat) origin: vec4<f32>,
    @location(7) @interpolate(flat) axis: vec4<f32>,
    @location(8) @interpolate(flat) bilinear: vec4<f32>,
    @location(9) @interpolate(flat) grid: vec4<u32>,
    // 1 / grid.z, 1 / grid.w and the patches along u (see `div_by`), once a rectangle.
    @location(10) @interpolate(flat) per_grid: vec4<f32>,
}

// One instance per rectangle; four vertices as a triangle strip.
@vertex
fn vs(@builtin(vertex_index) vi: u32, r: Rect) -> VsOut {
    var x = mix(r.rect.x, r.rect.y, f32(vi & 1u));
    var y = mix(r.rect.z, r.rect.w, f32(vi >> 1u));
    if (shot.own.z == 1u) {
        // Lattice mode: this rank's cells (t, p) = (c px + x0, r py + y0) are
        // packed into pixels (c, r); the map is affine, so rectangles stay rectangles.
        let grid = vec2<f32>(f32(shot.tiles.z), f32(shot.tiles.w));
        x = (x - f32(shot.own.x) - 0.5) / grid.x + 0.5;
        y = (y - f32(shot.own.y) - 0.5) / grid.y + 0.5;
        // The map divides the rectangle's margin by the grid; give it back
        // in pixels, well above the rasteriser's sub-pixel snap (1/256), so
        // no pixel centre on the edge is lost. The exact test decides anyway.
        x += select(-LATTICE_MARGIN, LATTICE_MARGIN, (vi & 1u) == 1u);
        y += select(-LATTICE_MARGIN, LATTICE_MARGIN, (vi >> 1u) == 1u);
    }
    var out: VsOut;
    out.pos = vec4<f32>(x / f32(shot.res.y) * 2.0 - 1.0, 1.0 - y / f32(shot.res.x) * 2.0, 0.5, 1.0);
    out.e0 = r.e0;
    out.e1 = r.e1;
    out.e2 = r.e2;
    out.e3 = r.e3;
    out.plane = r.plane;
    out.item = r.item;
    out.origin = r.origin;
    out.axis = r.axis;
    out.bilinear = r.bilinear;
    out.grid = r.grid;
    out.per_grid = grid_reciprocals(r.grid);
    return out;
}

// a / d for the small counts here (cells, tiles, elements) without an
// integer divide, which a CPU rasteriser runs lane by lane at tens of
// cycles each: (a + 0.5) / d lies at least 0.5 / d from any integer, far
// more than the few ulps f32 division may be off for a below 2^20, so the
// floor is the integer quotient exactly.
fn div_small(a: u32, d: u32) -> u32 {
    return u32(floor((f32(a) + 0.5) / f32(d)));
}

// a / d as `div_small`, given r = 1 / d rounded (a multiply, not a divide,
// a fragment): r is within 2.5 ulp of 1 / d (WGSL's division), so (a + 0.5) r
// is off by under 2^-22 (a + 0.5) / d, less than its 0.5 / d from any
// integer for a below 2^21; the floor is exact on every driver.
fn div_by(a: u32, r: f32) -> u32 {
    return u32(floor((f32(a) + 0.5) * r));
}

// a mod d, as `div_by`.
fn mod_by(a: u32, d: u32, r: f32) -> u32 {
    return a - div_by(a, r) * d;
}

// What `grid_element_of` divides by, once a rectangle: 1 / elements per
// patch along u and along v, and the patches along u.
fn grid_reciprocals(grid: vec4<u32>) -> vec4<f32> {
    let per = max(grid.zw, vec2<u32>(1u));
    return vec4<f32>(1.0 / f32(per.x), 1.0 / f32(per.y), f32(div_small(grid.x, per.x)), 0.0);
}

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

// (u, v) of the point h of a planar quad p(u, v) = u e + v f + u v g, e = (ex, 0)
// (Quilez's inverse bilinear map; the root inside the quad).
fn inverse_bilinear(h: vec2<f32>, ex: f32, f: vec2<f32>, g: vec2<f32>) -> vec2<f32> {
    let e = vec2<f32>(ex, 0.0);
    let k2 = cross2(g, f);
    let k1 = cross2(e, f) + cross2(h, g);
    let k0 = cross2(h, e);
    var v: f32;
    if (abs(k2) <= 1.0e-6 * abs(k1)) {
        v = -k0 / k1;
    } else {
        let w = sqrt(max(k1 * k1 - 4.0 * k0 * k2, 0.0));
        v = (-k1 - w) / (2.0 * k2);
        if (v < -0.01 || v > 1.01) {
            v = (-k1 + w) / (2.0 * k2);
        }
    }
    let u = (h.x - f.x * v) / (ex + g.x * v);
    return vec2<f32>(u, v);
}

// The element of a quad grid at the hit point p (shooter frame): `first` is
// the grid's first element, the rest as in `Rect`.
fn grid_element_of(
    first: u32,
    normal: vec3<f32>,
    origin: vec4<f32>,
    axis: vec4<f32>,
    bilinear: vec4<f32>,
    grid: vec4<u32>,
    per_grid: vec4<f32>,
    p: vec3<f32>,
) -> u32 {
    let x = axis.xyz;
    let y = cross(normal, x);
    let q = p - origin.xyz;
    let uv = inverse_bilinear(
        vec2<f32>(dot(q, x), dot(q, y)),
        bilinear.x,
        bilinear.yz,
        vec2<f32>(bilinear.w, origin.w),
    );
    let n = grid.xy;
    let iu = min(u32(max(uv.x, 0.0) * f32(n.x)), n.x - 1u);
    let iv = min(u32(max(uv.y, 0.0) * f32(n.y)), n.y - 1u);
    let per = grid.zw;
    let ru = per_grid.x;
    let rv = per_grid.y;
    let cell_patch = div_by(iv, rv) * u32(per_grid.z) + div_by(iu, ru);
    return first + cell_patch * per.x * per.y + mod_by(iv, per.y, rv) * per.x + mod_by(iu, per.x, ru);
}

fn grid_element(in: VsOut, p: vec3<f32>) -> u32 {
    return grid_element_of(in.item.x, in.plane.xyz, in.origin, in.axis, in.bilinear, in.grid, in.per_grid, p);
}

struct FsOut {
    @location(0) item: u32,
    @builtin(frag_depth) depth: f32,
}

// Cell-centre direction in the shooter's frame, from the f64 table.
fn cell_direction(cell: vec2<u32>) -> vec3<f32> {
    let polar = trig[cell.y].xy;
    let azimuth = trig[cell.x].zw;
    return vec3<f32>(polar.x * azimuth.x, polar.x * azimuth.y, polar.y);
}

// Whether this rank's tiles hold the cell (full-size image, not the lattice).
fn owns_cell(cell: vec2<u32>) -> bool {
    let owner = vec2<u32>(
        mod_by(div_by(cell.x, shot.per_tile.x), shot.tiles.z, shot.per_tile.z),
        mod_by(div_by(cell.y, shot.per_tile.y), shot.tiles.w, shot.per_tile.w),
    );
    return all(owner == shot.own.xy) && cell.x < shot.res.y && cell.y < shot.res.x;
}

@fragment
fn fs(in: VsOut) -> FsOut {
    var cell = vec2<u32>(in.pos.xy);
    if (shot.own.z == 1u) {
        cell = cell * shot.tiles.zw + shot.own.xy;
        if (cell.x >= shot.res.y || cell.y >= shot.res.x) {
            discard;
        }
    } else if (!owns_cell(cell)) {
        discard;
    }
    let dir = cell_direction(cell);
    if (dot(dir, in.e0) < -EDGE_TOL || dot(dir, in.e1) < -EDGE_TOL || dot(dir, in.e2) < -EDGE_TOL || dot(dir, in.e3) < -EDGE_TOL) {
        discard;
    }
    let cosine = dot(in.plane.xyz, dir);
    let t = in.plane.w / cosine;
    if (!(t > 0.0) || abs(cosine) < 1.0e-12) {
        discard;
    }
    var out: FsOut;
    if (in.item.y != 0u) {
        // Just behind a coincident front face, so the front wins the tie.
        out.item = BLOCKED;
        out.depth = min(t * shot.depth.x * (1.0 + 1.0e-5), 1.0);
    } else {
        var id = in.item.x;
        if (in.grid.x != 0u) {
            id = grid_element(in, dir * t);
        }
        out.item = id;
        out.depth = min(t * shot.depth.x, 1.0);
        if (shot.own.w == 1u) {
            atomicAdd(&coverage[id], 1u);
        }
    }
    return out;
}

// ---------------------------------------------------------------------------
// The tessellated projection (`--projection tessellated`): the CPU cuts each
// piece into triangles fine enough that every edge's equal-angle image is
// within a tolerance of its chord (clipped at the horizon, split at the
// seam and around the pole), and the vertex shader maps each vertex to
// (theta, phi) cell coordinates with depth = distance; fixed-function
// rasterisation does the rest (no per-cell edge test, no depth write).

struct Piece {
    plane: vec4<f32>,    // normal (shooter frame), offset
    item: vec4<u32>,     // first element, back-facing flag, -, -
    origin: vec4<f32>,
    axis: vec4<f32>,
    bilinear: vec4<f32>,
    grid: vec4<u32>,
}

@group(0) @binding(3) var<storage, read> pieces: array<Piece>;

struct TessVertex {
    @location(0) p: vec3<f32>,       // shooter frame
    @location(1) x_override: f32,    // >= 0: the column coordinate (pole vertices)
    @location(2) x_offset: f32,      // added to the column (seam unwrap and copies)
    @location(3) piece: u32,
}

struct TessOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) @interpolate(flat) piece: u32,
}

@vertex
fn vs_tess(v: TessVertex) -> TessOut {
    let rho = length(v.p.xy);
    var theta = atan2(v.p.y, v.p.x);
    if (theta < 0.0) {
        theta = theta + 6.28318530717959;
    }
    var x = theta / 6.28318530717959 * f32(shot.res.y);
    if (v.x_override >= 0.0) {
        x = v.x_override;
    }
    x = x + v.x_offset;
    let y = atan2(rho, v.p.z) / 1.57079632679490 * f32(shot.res.x);
    var depth = min(length(v.p) * shot.depth.x, 1.0);
    if (pieces[v.piece].item.y != 0u) {
        // Back faces lose a tie with a coincident front face.
        depth = min(depth * (1.0 + 1.0e-5), 1.0);
    }
    var out: TessOut;
    out.pos = vec4<f32>(x / f32(shot.res.y) * 2.0 - 1.0, 1.0 - y / f32(shot.res.x) * 2.0, depth, 1.0);
    out.piece = v.piece;
    return out;
}

@fragment
fn fs_tess(in: TessOut) -> @location(0) u32 {
    let cell = vec2<u32>(in.pos.xy);
    if (!owns_cell(cell)) {
        discard;
    }
    let pc = pieces[in.piece];
    if (pc.item.y != 0u) {
        return BLOCKED;
    }
    var id = pc.item.x;
    if (pc.grid.x != 0u) {
        let dir = cell_direction(cell);
        let cosine = dot(pc.plane.xyz, dir);
        let t = pc.plane.w / cosine;
        if (t > 0.0 && abs(cosine) > 1.0e-12) {
            id = grid_element_of(pc.item.x, pc.plane.xyz, pc.origin, pc.axis, pc.bilinear, pc.grid, grid_reciprocals(pc.grid), dir * t);
        }
    }
    if (shot.own.w == 1u) {
        atomicAdd(&coverage[id], 1u);
    }
    return id;
}
