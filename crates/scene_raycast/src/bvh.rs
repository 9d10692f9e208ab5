//! The scene's bounding volume hierarchy: a binned-SAH BVH2 over triangle pieces,
//! collapsed into a 4-wide BVH (the four children's boxes of a node side by side,
//! 128 bytes, tested in one pass of 4-lane SIMD slab tests), traversed nearest
//! child first, and closed by exact f64 Moeller-Trumbore triangle tests.
//!
//! Precision: node boxes are f32, relative to the centre of the scene's bounds,
//! and padded outward ([`BOX_MARGIN`], [`BOX_RELATIVE_MARGIN`]) so that no
//! rounding in the slab test can cull a box the exact ray meets. Before the
//! traversal the ray's origin is moved (in f64) to where the ray enters the
//! scene's bounds, so the f32 origin is never far from the boxes whatever the
//! camera's distance. The boxes only cull: every candidate triangle is
//! intersected in f64 from the original vertices, so the distances are those of
//! an exact f64 Moeller-Trumbore over every triangle.
//!
//! Leaves hold their triangles four to a [`TriangleBlock`], in f32, tested four
//! at once by a conservative Moeller-Trumbore filter ([`RayQuery::rejects`]):
//! it drops a triangle only when a forward error bound proves that the exact f64
//! test would miss it or find it beyond the nearest hit so far, so only the few
//! candidates that can be the answer are fetched and intersected in f64. The
//! answers are those of the f64 test over every triangle, bit for bit.
//!
//! Long thin triangles (the sides of diagonal lattice members) get one box per
//! piece (see [`SPLIT_EDGE`]); the triangle itself is never cut, so the surface
//! stays exactly the input's, without cracks.

use nalgebra::{Point3, Vector3};
use wide::{f32x4, CmpGt, CmpLe, CmpLt};

/// Triangles get one BVH box per piece (longest edge halved, recursively) while
/// their longest edge exceeds this many metres and is also more than
/// [`SPLIT_ASPECT`] times the triangle's height over it: the single box of a long
/// thin facet is mostly empty space.
pub const SPLIT_EDGE: f64 = 1.0;
/// See [`SPLIT_EDGE`].
pub const SPLIT_ASPECT: f64 = 4.0;
/// Absolute outward padding of the f32 node boxes, m.
const BOX_MARGIN: f64 = 1e-5;
/// Relative outward padding of the f32 node boxes (per unit of coordinate, m/m):
/// covers f32 rounding of the box corners, the ray's origin and its direction.
const BOX_RELATIVE_MARGIN: f64 = 2e-6;
/// |det| below this (relative to the edge lengths) is a ray in the triangle's plane.
const PARALLEL_DETERMINANT: f64 = 1e-14;
/// SAH bins per axis.
const BINS: usize = 16;
/// Cost of one level of the binary tree (half a 4-wide node visit) relative to
/// one [`TriangleBlock`] test: the SAH counts a leaf's cost in blocks, so leaves
/// fill their blocks (0.25 to 2, and leaves of 8 or 16, timed within noise on
/// the simulator's towers).
const TRAVERSAL_COST: f64 = 0.5;
/// Leaves never hold more pieces than this, whatever the SAH says.
const MAX_LEAF: usize = 8;
/// Below this depth the SAH chooses the splits; deeper, the median does, which
/// bounds the depth (and so the traversal stack) on any input.
const SAH_DEPTH: usize = 40;
/// Traversal stack entries: at most 3 per level of the 4-wide tree (each visit
/// pushes at most 4 and pops 1), whose depth is at most the BVH2's
/// ([`SAH_DEPTH`] plus the 34 median levels of 2^32 pieces), plus the root.
const STACK: usize = 3 * (SAH_DEPTH + 34) + 4;
/// Relative slack on f32 slab distances (PBRT's 1 + 2 gamma(3) and more).
const SLAB_SLACK: f32 = 1.0 + 1e-6;
/// Triangles per [`TriangleBlock`] (one f32 lane each).
const BLOCK: usize = 4;
/// Error bound of the f32 triangle filter, per unit of the product of the 1-norms
/// of its three factors (see [`RayQuery::rejects`]): 32 unit roundoffs of f32.
/// Each of the filter's triple products x . (y x z) is computed from inputs
/// rounded to f32 (the vertex and the ray's origin by one unit roundoff u each,
/// their difference by one more, the edges and the direction by one each: 4u of
/// perturbation) with five roundings of its own (gamma(5) ~ 5u), so it is within
/// about 9u |x|_1 |y|_1 |z|_1 of the exact value; the f64 test's own error, the
/// roundings of the filter's sums and of the bounds themselves add under 5u.
/// 32u leaves more than twice that.
const FILTER_ERROR: f32 = 16.0 * f32::EPSILON;
/// Weight of the f64 rounding terms (the unmoved origin's and the scene centre's
/// magnitudes, m) in the filter's error bound: 2^-30 x [`FILTER_ERROR`] exceeds
/// the f64 test's rounding of its triple products (about 8 x 2^-53) twice over.
const F64_ROUNDING_WEIGHT: f32 = 1.0 / (1u64 << 30) as f32;
/// Most rays in one packet of [`Bvh::cast_packet`] (one bit each of a mask).
pub(crate) const MAX_PACKET: usize = 64;

/// A node of the binary tree the build makes: its box and either its children
/// (`count == 0`: at `first` and `first + 1`) or its leaf's `count` pieces (in
/// the blocks of [`Bvh::blocks`] from `first` on once the leaves are packed;
/// `first..first + count` of the build's pieces before).
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    first: u32,
    hi: [f32; 3],
    count: u32,
}

/// A node of the traversed 4-wide tree: the boxes of its (up to) four children,
/// one lane each, and per child either a node (`count == 0`: `child` indexes
/// [`Bvh::nodes`]) or a leaf (`count` triangles in the blocks of [`Bvh::blocks`]
/// from `child` on).
/// An unused lane has the box lo = hi = +inf, which every ray misses.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node4 {
    lo: [[f32; 4]; 3],
    hi: [[f32; 4]; 3],
    child: [u32; 4],
    count: [u32; 4],
}

impl Node4 {
    const EMPTY: Self = Self {
        lo: [[f32::INFINITY; 4]; 3],
        hi: [[f32::INFINITY; 4]; 3],
        child: [0; 4],
        count: [0; 4],
    };
}

/// A triangle ready for the exact f64 Moeller-Trumbore test.
#[derive(Clone, Copy, Debug)]
struct ExactTriangle {
    a: Point3<f64>,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    /// |det| below this is a ray in the triangle's plane.
    parallel: f64,
}

/// Up to [`BLOCK`] triangles of a leaf in f32, one lane each, for the filter of
/// [`RayQuery::rejects`]: the first vertex relative to the scene's centre and the
/// two edges from it, each rounded to nearest from the f64 values that the exact
/// test uses. A leaf's last block may have unused lanes (see [`lanes`]).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct TriangleBlock {
    a: [[f32; BLOCK]; 3],
    e1: [[f32; BLOCK]; 3],
    e2: [[f32; BLOCK]; 3],
    /// Index of each lane's triangle (in [`Bvh::exact`]).
    triangle: [u32; BLOCK],
}

impl TriangleBlock {
    const EMPTY: Self = Self {
        a: [[0.0; BLOCK]; 3],
        e1: [[0.0; BLOCK]; 3],
        e2: [[0.0; BLOCK]; 3],
        triangle: [0; BLOCK],
    };
}

/// A box-bounded piece of a triangle during the build.
#[derive(Clone, Copy)]
struct Piece {
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    triangle: u32,
}

impl Piece {
    fn centroid(&self, axis: usize) -> f64 {
        0.5 * (self.lo[axis] + self.hi[axis])
    }
}

/// Axis-aligned box in f64 during the build.
#[derive(Clone, Copy)]
struct Bounds {
    lo: Vector3<f64>,
    hi: Vector3<f64>,
}

impl Bounds {
    const EMPTY: Self = Self {
        lo: Vector3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY),
        hi: Vector3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY),
    };

    fn grow(&mut self, lo: &Vector3<f64>, hi: &Vector3<f64>) {
        self.lo = self.lo.inf(lo);
        self.hi = self.hi.sup(hi);
    }

    fn join(mut self, other: &Bounds) -> Self {
        self.grow(&other.lo, &other.hi);
        self
    }

    /// Half the surface area (the SAH only compares ratios); 0 when empty.
    fn half_area(&self) -> f64 {
        let d = self.hi - self.lo;
        if d.x < 0.0 {
            return 0.0;
        }
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// The BVH of a scene.
pub(crate) struct Bvh {
    nodes: Vec<Node4>,
    /// The leaves' triangles in f32, each leaf's in consecutive blocks.
    blocks: Vec<TriangleBlock>,
    /// Every triangle of the scene, by index, for the exact test.
    exact: Vec<ExactTriangle>,
    /// W coordinates of the origin of the f32 node frame.
    center: Vector3<f64>,
    /// |center|_1, m (a term of the triangle filter's error bound).
    center_norm: f32,
    /// The scene's bounds in W, padded (the root's box in f64).
    bounds_lo: Vector3<f64>,
    bounds_hi: Vector3<f64>,
}

impl Bvh {
    /// Builds the BVH over validated input (every index in range, every
    /// triangle of positive area).
    pub(crate) fn build(points: &[Point3<f64>], triangles: &[[u32; 3]]) -> Self {
        let mut scene = Bounds::EMPTY;
        for p in points {
            scene.grow(&p.coords, &p.coords);
        }
        let center = 0.5 * (scene.lo + scene.hi);
        let mut pieces = triangle_pieces(points, triangles);
        let mut nodes = Vec::with_capacity(2 * pieces.len());
        nodes.push(Node {
            lo: [0.0; 3],
            first: 0,
            hi: [0.0; 3],
            count: 0,
        });
        // (node index, pieces range, depth)
        let mut work = vec![(0usize, 0usize, pieces.len(), 0usize)];
        while let Some((index, start, end, depth)) = work.pop() {
            let bounds = pieces[start..end].iter().fold(Bounds::EMPTY, |mut b, p| {
                b.grow(&p.lo, &p.hi);
                b
            });
            let (lo, hi) = padded_f32(&bounds, &center);
            let node = &mut nodes[index];
            node.lo = lo;
            node.hi = hi;
            match split(&mut pieces[start..end], &bounds, depth) {
                Some(mid) => {
                    let left = nodes.len();
                    for _ in 0..2 {
                        nodes.push(Node {
                            lo: [0.0; 3],
                            first: 0,
                            hi: [0.0; 3],
                            count: 0,
                        });
                    }
                    nodes[index].first = left as u32;
                    nodes[index].count = 0;
                    work.push((left, start, start + mid, depth + 1));
                    work.push((left + 1, start + mid, end, depth + 1));
                }
                None => {
                    let node = &mut nodes[index];
                    node.first = start as u32;
                    node.count = (end - start) as u32;
                }
            }
        }
        let exact: Vec<ExactTriangle> = (0..triangles.len())
            .map(|t| exact_triangle(points, triangles, t))
            .collect();
        let blocks = pack_leaves(&mut nodes, &pieces, &exact, &center);
        let pad = |v: &Vector3<f64>| v.map(|x| BOX_MARGIN + BOX_RELATIVE_MARGIN * x.abs());
        Self {
            nodes: collapse(&nodes),
            blocks,
            exact,
            center,
            center_norm: center.abs().sum() as f32,
            bounds_lo: scene.lo - pad(&scene.lo),
            bounds_hi: scene.hi + pad(&scene.hi),
        }
    }

    /// The nearest triangle the ray from `origin` along the unit `direction` meets
    /// within [0, `max_range`]: (distance, triangle). With `any`, the first
    /// triangle found within range instead (an occlusion test).
    #[inline]
    pub(crate) fn cast(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        max_range: f64,
        any: bool,
    ) -> Option<(f64, u32)> {
        let mut ray = self.query(origin, direction, max_range)?;
        // (child, count, entry distance): a node when count == 0, else a leaf.
        let mut stack = [(0u32, 0u32, 0.0f32); STACK];
        let mut depth = 0usize;
        // The next node or leaf to visit: the nearest child met, without a trip
        // through the stack; None pops the stack.
        let mut next = Some((0u32, 0u32));
        loop {
            let (child, count) = match next.take() {
                Some(visit) => visit,
                None => loop {
                    if depth == 0 {
                        return ray.best;
                    }
                    depth -= 1;
                    let (child, count, t_enter) = stack[depth];
                    // Skipped when a nearer hit was found since the push.
                    if t_enter <= ray.limit {
                        break (child, count);
                    }
                },
            };
            if count > 0 {
                for (b, block) in self.leaf(child, count).iter().enumerate() {
                    let block = LoadedBlock::new(block, lanes(count as usize, b));
                    if ray.test_block(&block, &self.exact, any) && any {
                        return ray.best;
                    }
                }
                continue;
            }
            let node = &self.nodes[child as usize];
            let (t_in, mask) = ray.slab.entries(node, ray.limit);
            let mask = mask.move_mask() as u32;
            if mask == 0 {
                continue;
            }
            if mask & (mask - 1) == 0 {
                let lane = mask.trailing_zeros() as usize;
                next = Some((node.child[lane], node.count[lane]));
                continue;
            }
            // Several met: visit the nearest next, push the others farthest first.
            let (order, n) = farthest_first(mask, &t_in.to_array());
            for &(lane, t) in &order[..n - 1] {
                // Cannot overflow (see STACK); a guard instead of a panic all the same.
                if depth < STACK {
                    stack[depth] = (node.child[lane], node.count[lane], t);
                    depth += 1;
                    self.prefetch(node.child[lane], node.count[lane]);
                }
            }
            let nearest = order[n - 1].0;
            next = Some((node.child[nearest], node.count[nearest]));
        }
    }

    /// Casts up to [`MAX_PACKET`] rays together (coherent ones: neighbouring pixels
    /// of a camera, shadow rays toward the sun): each node is fetched and ordered
    /// once for every ray that entered its box, which is what single rays spend
    /// most of their time on. Each ray's answer (its `best`) is the one
    /// [`Bvh::cast`] gives it: the nearest hit is decided by [`nearer`], which no
    /// visiting order changes, and the boxes only cull. With `any`, a ray stops at
    /// its first hit within range. Rays beyond [`MAX_PACKET`] are left untouched.
    pub(crate) fn cast_packet(&self, rays: &mut [RayQuery], any: bool) {
        let n = rays.len().min(MAX_PACKET);
        let rays = &mut rays[..n];
        // Rays still looking for a hit: an occlusion test drops a ray at its first.
        let mut live: u64 = if n == MAX_PACKET {
            u64::MAX
        } else {
            (1u64 << n) - 1
        };
        let bounds = PacketBounds::new(rays);
        // Rays that start at one point in the node frame (a camera inside the
        // scene's bounds) share each box's corners relative to it.
        let shared_origin = rays
            .first()
            .map(|r| r.slab.origin)
            .filter(|o| rays.iter().all(|r| r.slab.origin == *o));
        // (child, count, rays, the nearest of their entry distances).
        let mut stack = [(0u32, 0u32, 0u64, 0.0f32); STACK];
        let mut depth = 0usize;
        let mut next = Some((0u32, 0u32, live));
        loop {
            let (child, count, mask) = match next.take() {
                Some(visit) => visit,
                None => loop {
                    if depth == 0 {
                        return;
                    }
                    depth -= 1;
                    let (child, count, mask, t_enter) = stack[depth];
                    // A ray that found a hit nearer than every ray's entry since the
                    // push has nothing left to find there (its own entry is no nearer).
                    let mut keep = 0u64;
                    for r in bits(mask & live) {
                        if t_enter <= rays[r].limit {
                            keep |= 1 << r;
                        }
                    }
                    if keep != 0 {
                        break (child, count, keep);
                    }
                },
            };
            if count > 0 {
                // Each block loaded once for all the packet's rays that reach it.
                for (b, block) in self.leaf(child, count).iter().enumerate() {
                    let block = LoadedBlock::new(block, lanes(count as usize, b));
                    for r in bits(mask & live) {
                        if rays[r].test_block(&block, &self.exact, any) && any {
                            live &= !(1u64 << r);
                        }
                    }
                }
                if live == 0 {
                    return;
                }
                continue;
            }
            let node = &self.nodes[child as usize];
            // Rays from one point that all pass between the four boxes: one test, not one per ray.
            if bounds.as_ref().is_some_and(|b| b.all_miss(node)) {
                continue;
            }
            // Per child: the rays that meet its box, and the nearest of their entries.
            let mut lane_rays = [0u64; 4];
            let mut lane_entry = f32x4::splat(f32::INFINITY);
            let shared = shared_origin.map(|o| relative_corners(node, &o));
            for r in bits(mask) {
                let corners =
                    shared.unwrap_or_else(|| relative_corners(node, &rays[r].slab.origin));
                let (t_in, met) = rays[r].slab.entries_from(&corners, rays[r].limit);
                lane_entry = lane_entry.fast_min(met.blend(t_in, f32x4::splat(f32::INFINITY)));
                let m = met.move_mask() as u64;
                for (lane, lane_mask) in lane_rays.iter_mut().enumerate() {
                    *lane_mask |= ((m >> lane) & 1) << r;
                }
            }
            let met = lane_rays
                .iter()
                .enumerate()
                .fold(0u32, |acc, (lane, &m)| acc | (u32::from(m != 0) << lane));
            if met == 0 {
                continue;
            }
            let (order, n) = farthest_first(met, &lane_entry.to_array());
            for &(lane, t) in &order[..n - 1] {
                // Cannot overflow (see STACK); a guard instead of a panic all the same.
                if depth < STACK {
                    stack[depth] = (node.child[lane], node.count[lane], lane_rays[lane], t);
                    depth += 1;
                    self.prefetch(node.child[lane], node.count[lane]);
                }
            }
            let nearest = order[n - 1].0;
            next = Some((node.child[nearest], node.count[nearest], lane_rays[nearest]));
        }
    }

    /// The traversal state of the ray from `origin` along the unit `direction`,
    /// hits within [0, `max_range`]; None when it cannot meet the scene.
    #[inline(always)]
    pub(crate) fn query(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        max_range: f64,
    ) -> Option<RayQuery> {
        let (enter, exit) = self.scene_span(origin, direction)?;
        if enter > max_range {
            return None;
        }
        let slab = SlabRay::new(
            &(origin.coords + direction * enter - self.center),
            direction,
        );
        let local_origin = [0, 1, 2].map(|k| (origin[k] - self.center[k]) as f32);
        let dir = [0, 1, 2].map(|k| direction[k] as f32);
        let norm1 = |v: [f32; 3]| v[0].abs() + v[1].abs() + v[2].abs();
        // The filter's |s|_1 bound, less the vertex's share (see `rejects`), and the
        // f64 test's rounding on the unmoved origin, the centre and the move.
        let origin_norm = norm1(slab.origin)
            + F64_ROUNDING_WEIGHT * (norm1(local_origin) + self.center_norm + enter as f32);
        let mut ray = RayQuery {
            origin: *origin,
            direction: *direction,
            max_range,
            slab,
            dir,
            error_d: FILTER_ERROR * norm1(dir),
            origin_norm,
            // Every point of the scene lies ahead of a moved origin (it stops
            // BOX_MARGIN before the bounds): only an origin inside needs t >= 0.
            behind: if enter > 0.0 { f32::NEG_INFINITY } else { 0.0 },
            local_origin,
            enter,
            exit,
            limit: 0.0,
            filter_limit: 0.0,
            best: None,
        };
        ray.limit = ray.limit_of(max_range);
        ray.filter_limit = ray.filter_limit_of(max_range);
        Some(ray)
    }

    /// Asks the CPU to start loading the node (`count == 0`) or the first leaf
    /// block at `child`, which the traversal pops later: a node's visit waits
    /// mostly on memory, and the loads of the pushed siblings then overlap it.
    #[inline(always)]
    fn prefetch(&self, child: u32, count: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            let line = if count == 0 {
                self.nodes
                    .get(child as usize)
                    .map(|n| n as *const Node4 as *const i8)
            } else {
                self.blocks
                    .get(child as usize)
                    .map(|b| b as *const TriangleBlock as *const i8)
            };
            if let Some(p) = line {
                // SAFETY: SSE is part of every x86_64 target, and a prefetch is only
                // a hint: it never faults nor reads into the program (both lines
                // lie within the node or the block, 128 and 160 bytes).
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(p);
                    _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64));
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (child, count);
    }

    /// The blocks of the leaf of `count` triangles at block `first`.
    #[inline(always)]
    fn leaf(&self, first: u32, count: u32) -> &[TriangleBlock] {
        let first = first as usize;
        let end = (first + blocks_of(count as usize)).min(self.blocks.len());
        self.blocks.get(first..end).unwrap_or(&[])
    }

    /// Where the ray enters and leaves the scene's (padded) bounds, in f64:
    /// (max(entry, 0), exit), or None when it misses them.
    #[inline]
    fn scene_span(&self, origin: &Point3<f64>, direction: &Vector3<f64>) -> Option<(f64, f64)> {
        let mut enter = 0.0f64;
        let mut exit = f64::INFINITY;
        for k in 0..3 {
            let (o, d) = (origin[k], direction[k]);
            if d == 0.0 {
                if o < self.bounds_lo[k] || o > self.bounds_hi[k] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d;
            let t1 = (self.bounds_lo[k] - o) * inv;
            let t2 = (self.bounds_hi[k] - o) * inv;
            enter = enter.max(t1.min(t2));
            exit = exit.min(t1.max(t2));
        }
        // Moving the origin to the entry is exact to f64 rounding; step back a
        // hair so that rounding never puts it past a surface on the boundary.
        let enter = (enter - BOX_MARGIN).max(0.0);
        (enter <= exit).then_some((enter, exit + BOX_MARGIN))
    }
}

/// The ray in the f32 node frame, ready for 4-lane slab tests.
#[derive(Clone, Copy)]
struct SlabRay {
    // Scalars, splat at each test: a packet holds 64 of these, copied in place.
    origin: [f32; 3],
    inv_dir: [f32; 3],
}

impl SlabRay {
    fn new(local_origin: &Vector3<f64>, direction: &Vector3<f64>) -> Self {
        // A zero component becomes a tiny one of the same sign: the slab test then
        // needs no special case (the padded boxes absorb the difference).
        let inv = |c: f64| {
            let c = c as f32;
            let c = if c.abs() < 1e-30 {
                1e-30f32.copysign(c)
            } else {
                c
            };
            1.0 / c
        };
        Self {
            origin: [0, 1, 2].map(|k| local_origin[k] as f32),
            inv_dir: [inv(direction.x), inv(direction.y), inv(direction.z)],
        }
    }

    /// Distances at which the ray enters the boxes of `node`'s four children (0
    /// from inside), and the lanes of those it meets no farther than `limit`
    /// (all bits set in a lane met).
    #[inline(always)]
    fn entries(&self, node: &Node4, limit: f32) -> (f32x4, f32x4) {
        self.entries_from(&relative_corners(node, &self.origin), limit)
    }

    /// [`SlabRay::entries`] from the boxes' corners relative to the ray's origin
    /// ([`relative_corners`]).
    #[inline(always)]
    fn entries_from(&self, corners: &Corners, limit: f32) -> (f32x4, f32x4) {
        let (lo, hi) = corners;
        let slab = |k: usize| {
            let inv_dir = f32x4::splat(self.inv_dir[k]);
            let t1 = lo[k] * inv_dir;
            let t2 = hi[k] * inv_dir;
            (t1.fast_min(t2), t1.fast_max(t2))
        };
        let (x_in, x_out) = slab(0);
        let (y_in, y_out) = slab(1);
        let (z_in, z_out) = slab(2);
        let t_in = x_in.fast_max(y_in).fast_max(z_in).fast_max(f32x4::ZERO);
        let t_out = x_out.fast_min(y_out).fast_min(z_out) * f32x4::splat(SLAB_SLACK);
        let met = t_in.cmp_le(t_out) & t_in.cmp_le(f32x4::splat(limit));
        (t_in, met)
    }
}

/// The low and high corners of a node's four boxes, per axis, relative to a point.
type Corners = ([f32x4; 3], [f32x4; 3]);

/// The corners of `node`'s boxes relative to `origin` (node frame).
#[inline(always)]
fn relative_corners(node: &Node4, origin: &[f32; 3]) -> Corners {
    let rel = |c: &[[f32; 4]; 3]| [0, 1, 2].map(|k| f32x4::new(c[k]) - f32x4::splat(origin[k]));
    (rel(&node.lo), rel(&node.hi))
}

/// Absolute padding (m) of the boxes in [`PacketBounds::all_miss`], on top of
/// the boxes' own: covers the f32 rounding of a shared origin up to kilometres
/// from the scene's centre together with [`PACKET_RELATIVE_MARGIN`].
const PACKET_MARGIN: f32 = 1e-4;
/// Relative padding of the same boxes, per metre of the origin's distance from
/// the scene's centre (several f32 epsilons).
const PACKET_RELATIVE_MARGIN: f32 = 1e-6;
/// Relative widening of the packet's inverse-direction intervals and slack on
/// its distances (far above f32 rounding).
const PACKET_SLACK: f32 = 1e-5;

/// The rays of a packet that share their origin, bounded together: per axis the
/// interval of their inverse directions. A node's box that the whole bundle
/// misses (interval arithmetic, padded) is missed by every ray of the packet,
/// so the node needs no test per ray.
struct PacketBounds {
    origin: [f32x4; 3],
    /// Interval of the rays' 1/d along each axis, widened outward.
    inv_lo: [f32x4; 3],
    inv_hi: [f32x4; 3],
    /// Whether every ray's direction has the same sign along the axis (otherwise
    /// the axis bounds nothing).
    bounded: [bool; 3],
    /// Whether the rays go toward +axis (on the bounded axes).
    positive: [bool; 3],
    margin: f32x4,
}

impl PacketBounds {
    /// The bounds of `rays` when they all start at one point (None otherwise).
    fn new(rays: &[RayQuery]) -> Option<Self> {
        let first = rays.first()?;
        if rays.iter().any(|r| r.origin != first.origin) {
            return None;
        }
        let local = [0, 1, 2].map(|k| first.local_origin[k]);
        let reach = local.iter().fold(0.0f32, |m, c| m.max(c.abs()));
        let mut inv_lo = [f32::INFINITY; 3];
        let mut inv_hi = [f32::NEG_INFINITY; 3];
        for ray in rays {
            for k in 0..3 {
                let inv = ray.slab.inv_dir[k];
                inv_lo[k] = inv_lo[k].min(inv);
                inv_hi[k] = inv_hi[k].max(inv);
            }
        }
        let positive = [0, 1, 2].map(|k| inv_lo[k] > 0.0);
        let bounded = [0, 1, 2].map(|k| positive[k] || inv_hi[k] < 0.0);
        Some(Self {
            origin: local.map(f32x4::splat),
            inv_lo: [0, 1, 2].map(|k| f32x4::splat(inv_lo[k] - inv_lo[k].abs() * PACKET_SLACK)),
            inv_hi: [0, 1, 2].map(|k| f32x4::splat(inv_hi[k] + inv_hi[k].abs() * PACKET_SLACK)),
            bounded,
            positive,
            margin: f32x4::splat(PACKET_MARGIN + PACKET_RELATIVE_MARGIN * reach),
        })
    }

    /// True when no ray of the packet can meet any of `node`'s four boxes.
    #[inline(always)]
    fn all_miss(&self, node: &Node4) -> bool {
        let mut near = f32x4::ZERO;
        let mut far = f32x4::splat(f32::INFINITY);
        for k in 0..3 {
            if !self.bounded[k] {
                continue;
            }
            let lo = f32x4::new(node.lo[k]) - self.origin[k] - self.margin;
            let hi = f32x4::new(node.hi[k]) - self.origin[k] + self.margin;
            // A ray enters the slab at its near face and leaves at its far face;
            // along 1/d in [inv_lo, inv_hi] those distances are linear in 1/d.
            let (enter, leave) = if self.positive[k] { (lo, hi) } else { (hi, lo) };
            near = near.fast_max((enter * self.inv_lo[k]).fast_min(enter * self.inv_hi[k]));
            far = far.fast_min((leave * self.inv_lo[k]).fast_max(leave * self.inv_hi[k]));
        }
        let met = near.cmp_le(far * f32x4::splat(1.0 + PACKET_SLACK));
        met.move_mask() == 0
    }
}

/// One ray during a traversal: the ray in f64 for the triangle tests, in the f32
/// node frame for the box tests, and the nearest hit found so far.
#[derive(Clone, Copy)]
pub(crate) struct RayQuery {
    origin: Point3<f64>,
    direction: Vector3<f64>,
    max_range: f64,
    slab: SlabRay,
    /// The unit direction in f32, for the triangle filter.
    dir: [f32; 3],
    /// [`FILTER_ERROR`] times |dir|_1.
    error_d: f32,
    /// |slab.origin|_1 plus the f64 rounding terms: with a vertex's |a|_1, a bound
    /// on |s|_1 of the filter (see [`RayQuery::rejects`]).
    origin_norm: f32,
    /// The least T (t det) in the node frame that the filter keeps: 0 for a ray
    /// starting inside the scene's bounds (hits at t < 0 do not count), minus
    /// infinity for a moved origin (nothing of the scene lies behind it).
    behind: f32,
    /// The ray's origin in the f32 node frame (before the move to the scene's bounds).
    local_origin: [f32; 3],
    /// The f32 frame's origin sits this far along the ray (where it enters the
    /// scene's bounds), m; node distances are measured from there.
    enter: f64,
    /// Where the ray leaves the scene's bounds, m.
    exit: f64,
    /// Node boxes entered farther than this (f32 frame) hold no nearer hit.
    limit: f32,
    /// Triangles met farther than this (f32 frame, rounded up) are no nearer hit.
    filter_limit: f32,
    best: Option<(f64, u32)>,
}

impl RayQuery {
    /// The nearest hit found: (distance, triangle).
    pub(crate) fn best(&self) -> Option<(f64, u32)> {
        self.best
    }

    /// The node-frame limit of a hit at distance `t` along the ray, padded.
    #[inline(always)]
    fn limit_of(&self, t: f64) -> f32 {
        ((t.min(self.exit) - self.enter) as f32 + 1e-4) * SLAB_SLACK
    }

    /// The filter's limit of a hit at distance `t`: t - enter in f32, rounded up,
    /// and never below 0 (no triangle the exact test keeps lies nearer).
    #[inline(always)]
    fn filter_limit_of(&self, t: f64) -> f32 {
        ((t - self.enter) as f32).next_up().max(0.0)
    }

    /// Tests the triangles of a leaf's block, keeping the nearest hit within
    /// range; true when one of them became the nearest (with `any`, stops there).
    /// The f32 filter drops the triangles that cannot be that hit; the others are
    /// intersected exactly (`exact`).
    #[inline(always)]
    fn test_block(&mut self, block: &LoadedBlock, exact: &[ExactTriangle], any: bool) -> bool {
        let mut found = false;
        let mut candidates = block.lanes & !self.rejects(block);
        while candidates != 0 {
            let lane = candidates.trailing_zeros() as usize;
            candidates &= candidates - 1;
            let triangle = block.triangle[lane];
            let Some(piece) = exact.get(triangle as usize) else {
                continue;
            };
            if let Some(t) = intersect(piece, &self.origin, &self.direction) {
                let hit = (t, triangle);
                if t <= self.max_range && self.best.is_none_or(|best| nearer(hit, best)) {
                    self.best = Some(hit);
                    found = true;
                    if any {
                        return true;
                    }
                    self.limit = self.limit_of(t);
                    self.filter_limit = self.filter_limit_of(t);
                }
            }
        }
        found
    }

    /// The lanes of `block` (bits) whose triangle the exact test
    /// ([`intersect`]) surely misses, or meets behind the ray's start or beyond
    /// [`RayQuery::filter_limit`]; the others are candidates.
    ///
    /// Moeller-Trumbore in f32 without the division, from the moved origin o'
    /// (node frame): s = o' - a, det = e1 . (d x e2), U = s . (d x e2),
    /// V = d . (s x e1), T = e2 . (s x e1); the exact test meets the triangle
    /// when U, V >= 0 and U + V <= det (det > 0, signs flipped otherwise), at
    /// t = T / det + enter. Moving the origin along d changes only T (by
    /// -enter det). Each computed triple product is within [`FILTER_ERROR`] times
    /// the product of its factors' 1-norms of what the exact test computes, so a
    /// lane is rejected only where a condition fails by more than that bound: Embree
    /// tests watertight in f32 and decides; this test only decides what is
    /// surely out, and the f64 test decides the rest, the answers staying exact.
    /// A lane whose det is within its bound of 0 (sign unknown) is never
    /// rejected, and neither is one with NaN or infinite terms (every comparison
    /// below is false for NaN).
    #[inline(always)]
    fn rejects(&self, block: &LoadedBlock) -> u32 {
        let (a, e1, e2) = (&block.a, &block.e1, &block.e2);
        let d = self.dir.map(f32x4::splat);
        let o = self.slab.origin.map(f32x4::splat);
        let s = [o[0] - a[0], o[1] - a[1], o[2] - a[2]];
        let cross = |x: &[f32x4; 3], y: &[f32x4; 3]| {
            [
                x[1] * y[2] - x[2] * y[1],
                x[2] * y[0] - x[0] * y[2],
                x[0] * y[1] - x[1] * y[0],
            ]
        };
        let dot = |x: &[f32x4; 3], y: &[f32x4; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
        let p = cross(&d, e2);
        let q = cross(&s, e1);
        let det = dot(e1, &p);
        // The sign of det, moved onto U, V and T (as if det > 0).
        let sign = det & f32x4::splat(-0.0);
        let u = dot(&s, &p) ^ sign;
        let w = dot(&d, &q) ^ sign;
        let t = dot(e2, &q) ^ sign;
        let det = det.abs();
        let (n1, n2) = (block.norm_e1, block.norm_e2);
        // |s|_1 <= |o'|_1 + |a|_1 for the computed and the exact s alike.
        let ns = f32x4::splat(self.origin_norm) + block.norm_a;
        let error_d = f32x4::splat(self.error_d);
        let err_det = error_d * block.norm_e1e2;
        let err_u = error_d * ns * n2;
        let err_v = error_d * ns * n1;
        let err_t = f32x4::splat(FILTER_ERROR) * ns * block.norm_e1e2;
        let known = det.cmp_gt(err_det);
        let out = u.cmp_lt(-err_u)
            | w.cmp_lt(-err_v)
            | (u + w).cmp_gt(det + err_u + err_v + err_det)
            | (t + err_t).cmp_lt(f32x4::splat(self.behind))
            | t.cmp_gt(f32x4::splat(self.filter_limit) * (det + err_det) + err_t);
        (known & out).move_mask() as u32
    }
}

/// A [`TriangleBlock`] in registers, with the 1-norms of its vectors that the
/// filter's error bounds need (the same for every ray that tests it).
struct LoadedBlock {
    a: [f32x4; 3],
    e1: [f32x4; 3],
    e2: [f32x4; 3],
    norm_a: f32x4,
    norm_e1: f32x4,
    norm_e2: f32x4,
    norm_e1e2: f32x4,
    triangle: [u32; BLOCK],
    /// The lanes in use (bits).
    lanes: u32,
}

impl LoadedBlock {
    #[inline(always)]
    fn new(block: &TriangleBlock, lanes: u32) -> Self {
        let v = |c: &[[f32; BLOCK]; 3]| c.map(f32x4::new);
        let norm1 = |x: &[f32x4; 3]| x[0].abs() + x[1].abs() + x[2].abs();
        let (a, e1, e2) = (v(&block.a), v(&block.e1), v(&block.e2));
        let (norm_e1, norm_e2) = (norm1(&e1), norm1(&e2));
        Self {
            norm_a: norm1(&a),
            norm_e1,
            norm_e2,
            norm_e1e2: norm_e1 * norm_e2,
            a,
            e1,
            e2,
            triangle: block.triangle,
            lanes,
        }
    }
}

/// Blocks holding `count` triangles.
#[inline(always)]
fn blocks_of(count: usize) -> usize {
    count.div_ceil(BLOCK)
}

/// The used lanes (bits) of block `b` of a leaf of `count` triangles.
#[inline(always)]
fn lanes(count: usize, b: usize) -> u32 {
    let used = count.saturating_sub(b * BLOCK).min(BLOCK);
    (1u32 << used) - 1
}

/// Whether hit `a` (distance, triangle) is nearer than `b`; at the same distance
/// the lower triangle index is, so that the answer does not depend on the order in
/// which the traversal meets them (single rays and packets agree exactly).
#[inline(always)]
fn nearer(a: (f64, u32), b: (f64, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// The lanes set in `mask` (at least one), sorted by entry distance `t_in`,
/// farthest first: (lane, entry) and their number.
#[inline(always)]
fn farthest_first(mut mask: u32, t_in: &[f32; 4]) -> ([(usize, f32); 4], usize) {
    let mut order = [(0usize, 0.0f32); 4];
    let mut n = 0;
    while mask != 0 {
        let lane = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        let t = t_in[lane];
        let mut k = n;
        while k > 0 && order[k - 1].1 < t {
            order[k] = order[k - 1];
            k -= 1;
        }
        order[k] = (lane, t);
        n += 1;
    }
    (order, n)
}

/// The indices of the bits set in `mask`, lowest first.
#[inline(always)]
fn bits(mut mask: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let bit = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            bit
        })
    })
}

/// Distance along the unit `direction` at which the ray meets `leaf`'s triangle
/// (either side), f64 Moeller-Trumbore; None if it does not.
#[inline(always)]
fn intersect(leaf: &ExactTriangle, origin: &Point3<f64>, direction: &Vector3<f64>) -> Option<f64> {
    let p = direction.cross(&leaf.e2);
    let det = leaf.e1.dot(&p);
    if det.abs() < leaf.parallel {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - leaf.a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&leaf.e1);
    let v = direction.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let distance = leaf.e2.dot(&q) * inv;
    (distance >= 0.0).then_some(distance)
}

/// The 4-wide tree of the binary tree `nodes` (root at 0): each 4-wide node
/// takes the children of a binary node and opens the largest of them that are
/// interior until it holds four.
fn collapse(nodes: &[Node]) -> Vec<Node4> {
    let mut out = vec![Node4::EMPTY];
    let root = nodes[0];
    if root.count > 0 {
        set_lane(&mut out[0], 0, &root, root.first);
        return out;
    }
    // (binary node whose children fill it, 4-wide node to fill)
    let mut work = vec![(0usize, 0usize)];
    while let Some((binary, wide_index)) = work.pop() {
        let first = nodes[binary].first as usize;
        let mut lanes: Vec<usize> = vec![first, first + 1];
        while lanes.len() < 4 {
            let widest = lanes
                .iter()
                .enumerate()
                .filter(|(_, &b)| nodes[b].count == 0)
                .max_by(|(_, &a), (_, &b)| half_area(&nodes[a]).total_cmp(&half_area(&nodes[b])));
            let Some((slot, &open)) = widest else { break };
            let children = nodes[open].first as usize;
            lanes[slot] = children;
            lanes.push(children + 1);
        }
        for (lane, &b) in lanes.iter().enumerate() {
            let node = nodes[b];
            let child = if node.count > 0 {
                node.first
            } else {
                out.push(Node4::EMPTY);
                work.push((b, out.len() - 1));
                (out.len() - 1) as u32
            };
            set_lane(&mut out[wide_index], lane, &node, child);
        }
    }
    out
}

fn set_lane(wide: &mut Node4, lane: usize, node: &Node, child: u32) {
    for k in 0..3 {
        wide.lo[k][lane] = node.lo[k];
        wide.hi[k][lane] = node.hi[k];
    }
    wide.child[lane] = child;
    wide.count[lane] = node.count;
}

fn half_area(node: &Node) -> f32 {
    let d = [0, 1, 2].map(|k| node.hi[k] - node.lo[k]);
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

fn exact_triangle(points: &[Point3<f64>], triangles: &[[u32; 3]], t: usize) -> ExactTriangle {
    let [ia, ib, ic] = triangles[t];
    let a = points[ia as usize];
    let e1 = points[ib as usize] - a;
    let e2 = points[ic as usize] - a;
    ExactTriangle {
        a,
        e1,
        e2,
        parallel: PARALLEL_DETERMINANT * e1.norm() * e2.norm(),
    }
}

/// Packs each leaf's pieces (`first..first + count` of `pieces`) into blocks of
/// [`BLOCK`] triangles and points the leaf at its first block.
fn pack_leaves(
    nodes: &mut [Node],
    pieces: &[Piece],
    exact: &[ExactTriangle],
    center: &Vector3<f64>,
) -> Vec<TriangleBlock> {
    let mut blocks = Vec::with_capacity(pieces.len() / 2);
    let mut triangles: Vec<u32> = Vec::with_capacity(MAX_LEAF);
    for node in nodes.iter_mut().filter(|n| n.count > 0) {
        let first = node.first as usize;
        // Pieces of one long triangle often share a leaf: the triangle once is enough.
        triangles.clear();
        for piece in &pieces[first..first + node.count as usize] {
            if !triangles.contains(&piece.triangle) {
                triangles.push(piece.triangle);
            }
        }
        node.first = blocks.len() as u32;
        node.count = triangles.len() as u32;
        for chunk in triangles.chunks(BLOCK) {
            let mut block = TriangleBlock::EMPTY;
            for (lane, &triangle) in chunk.iter().enumerate() {
                let tri = &exact[triangle as usize];
                let a = tri.a.coords - center;
                for k in 0..3 {
                    block.a[k][lane] = a[k] as f32;
                    block.e1[k][lane] = tri.e1[k] as f32;
                    block.e2[k][lane] = tri.e2[k] as f32;
                }
                block.triangle[lane] = triangle;
            }
            blocks.push(block);
        }
    }
    blocks
}

/// The f32 box of `bounds` relative to `center`, padded outward.
fn padded_f32(bounds: &Bounds, center: &Vector3<f64>) -> ([f32; 3], [f32; 3]) {
    let lo = bounds.lo - center;
    let hi = bounds.hi - center;
    let pad = |x: f64| BOX_MARGIN + BOX_RELATIVE_MARGIN * x.abs();
    (
        [0, 1, 2].map(|k| (lo[k] - pad(lo[k])) as f32),
        [0, 1, 2].map(|k| (hi[k] + pad(hi[k])) as f32),
    )
}

/// Partitions `pieces` for a node with `bounds` at `depth`: Some(number of
/// pieces on the left), or None to make a leaf.
fn split(pieces: &mut [Piece], bounds: &Bounds, depth: usize) -> Option<usize> {
    let n = pieces.len();
    if n <= 1 {
        return None;
    }
    let mut centroids = Bounds::EMPTY;
    for p in pieces.iter() {
        let c = 0.5 * (p.lo + p.hi);
        centroids.grow(&c, &c);
    }
    let extent = centroids.hi - centroids.lo;
    let axis = extent.imax();
    if extent[axis] <= 0.0 {
        // Every centroid in one point: no plane separates them.
        return (n > MAX_LEAF).then_some(n / 2);
    }
    if depth >= SAH_DEPTH {
        return Some(median_split(pieces, axis));
    }
    let leaf_cost = blocks_of(n) as f64;
    let parent_area = bounds.half_area();
    let mut best: Option<(f64, usize, f64)> = None; // (cost, axis, plane)
    for axis in 0..3 {
        let (lo, width) = (centroids.lo[axis], extent[axis]);
        if width <= 0.0 {
            continue;
        }
        let scale = BINS as f64 / width;
        let bin_of = |c: f64| (((c - lo) * scale) as usize).min(BINS - 1);
        let mut boxes = [Bounds::EMPTY; BINS];
        let mut counts = [0usize; BINS];
        for p in pieces.iter() {
            let b = bin_of(p.centroid(axis));
            boxes[b].grow(&p.lo, &p.hi);
            counts[b] += 1;
        }
        // Sweep from the right, then from the left, evaluating each plane.
        let mut right_area = [0.0f64; BINS];
        let mut right_count = [0usize; BINS];
        let mut acc = Bounds::EMPTY;
        let mut count = 0;
        for b in (1..BINS).rev() {
            acc = acc.join(&boxes[b]);
            count += counts[b];
            right_area[b] = acc.half_area();
            right_count[b] = count;
        }
        let mut acc = Bounds::EMPTY;
        let mut count = 0;
        for b in 0..BINS - 1 {
            acc = acc.join(&boxes[b]);
            count += counts[b];
            let (rc, ra) = (right_count[b + 1], right_area[b + 1]);
            if count == 0 || rc == 0 {
                continue;
            }
            let cost = TRAVERSAL_COST
                + (acc.half_area() * blocks_of(count) as f64 + ra * blocks_of(rc) as f64)
                    / parent_area.max(f64::MIN_POSITIVE);
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, lo + (b + 1) as f64 / scale));
            }
        }
    }
    match best {
        Some((cost, axis, plane)) if cost < leaf_cost || n > MAX_LEAF => {
            let scale = BINS as f64 / extent[axis];
            let lo = centroids.lo[axis];
            let bin_of = |c: f64| (((c - lo) * scale) as usize).min(BINS - 1);
            let plane_bin = ((plane - lo) * scale).round() as usize;
            let mid = partition(pieces, |p| bin_of(p.centroid(axis)) < plane_bin);
            if mid == 0 || mid == n {
                return Some(median_split(pieces, axis));
            }
            Some(mid)
        }
        Some(_) => None,
        None => (n > MAX_LEAF).then(|| median_split(pieces, axis)),
    }
}

/// Splits at the median centroid along `axis`; returns the left count (n / 2).
fn median_split(pieces: &mut [Piece], axis: usize) -> usize {
    let mid = pieces.len() / 2;
    pieces.select_nth_unstable_by(mid, |a, b| a.centroid(axis).total_cmp(&b.centroid(axis)));
    mid
}

/// Moves the pieces for which `left` holds to the front; returns their count.
fn partition(pieces: &mut [Piece], left: impl Fn(&Piece) -> bool) -> usize {
    let mut mid = 0;
    for i in 0..pieces.len() {
        if left(&pieces[i]) {
            pieces.swap(i, mid);
            mid += 1;
        }
    }
    mid
}

/// One piece per triangle, or several for a long thin one (see [`SPLIT_EDGE`]).
fn triangle_pieces(points: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<Piece> {
    let mut pieces = Vec::with_capacity(triangles.len());
    let mut stack: Vec<[Point3<f64>; 3]> = Vec::new();
    for (t, tri) in triangles.iter().enumerate() {
        stack.push(tri.map(|i| points[i as usize]));
        while let Some(c) = stack.pop() {
            if needs_split(&c) {
                // Halve the longest edge (a, b); o is the corner opposite it.
                let k = (0..3)
                    .max_by(|&i, &j| edge(&c, i).total_cmp(&edge(&c, j)))
                    .unwrap_or(0);
                let (a, b, o) = (c[(k + 1) % 3], c[(k + 2) % 3], c[k]);
                let m = Point3::from((a.coords + b.coords) * 0.5);
                stack.push([o, a, m]);
                stack.push([o, m, b]);
            } else {
                let mut bounds = Bounds::EMPTY;
                for p in &c {
                    bounds.grow(&p.coords, &p.coords);
                }
                pieces.push(Piece {
                    lo: bounds.lo,
                    hi: bounds.hi,
                    triangle: t as u32,
                });
            }
        }
    }
    pieces
}

/// Length of the edge opposite corner `k`.
fn edge(c: &[Point3<f64>; 3], k: usize) -> f64 {
    (c[(k + 1) % 3] - c[(k + 2) % 3]).norm()
}

fn needs_split(c: &[Point3<f64>; 3]) -> bool {
    let longest = (0..3).map(|k| edge(c, k)).fold(0.0, f64::max);
    let twice_area = (c[1] - c[0]).cross(&(c[2] - c[0])).norm();
    let height = twice_area / longest;
    longest > SPLIT_EDGE && longest > SPLIT_ASPECT * height
}
