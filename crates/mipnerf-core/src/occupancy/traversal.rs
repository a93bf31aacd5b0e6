//! Rays through the grid: the spans of a ray its cone may see occupied (a voxel traversal, or
//! even steps of the normalised distance in a contracted grid), and the rays that meet any.

use super::{CONTRACTED_STEPS_PER_CELL, MAX_DILATION, OccupancyGrid};
use crate::cone::Ray;

impl OccupancyGrid {
    /// The indices (ascending) of the `rays` that meet an occupied cell: those that
    /// [`ray_segments`](Self::ray_segments) gives a span, the only ones guided sampling runs the
    /// MLP on (the others render the background).
    #[must_use]
    pub fn active_rays(&self, rays: &[Ray]) -> Vec<u32> {
        use rayon::prelude::*;
        let hit: Vec<bool> = rays
            .par_iter()
            .map_init(Vec::new, |spans, r| {
                spans.clear();
                self.ray_segments(r, spans);
                !spans.is_empty()
            })
            .collect();
        hit.iter().enumerate().filter(|(_, h)| **h).map(|(i, _)| i as u32).collect()
    }

    /// The parts of `ray` (`origin + t direction`, `t` in `[near, far]`, in units of the
    /// direction, which need not be unit length) that its cone may see occupied, as sorted,
    /// disjoint `[t0, t1]` spans: a voxel traversal (Amanatides and Woo) of the cells the ray's
    /// axis crosses inside the grid's cube, consecutive hits merged. Space outside the cube is
    /// empty. Appends to `out`.
    ///
    /// A cone is wider than its axis: a cell counts as hit when an occupied cell lies within `k`
    /// cells of it, with `k = ceil(2 r / h)` for the cone's radius `r` (`radius · t`) where it
    /// leaves the cube and the cell side `h` (at most [`MAX_DILATION`]; `k = 0`, the axis alone,
    /// for a ray of zero radius). So a coarse pixel whose footprint covers the object but whose
    /// centre line misses it still samples it.
    pub fn ray_segments(&self, ray: &Ray, out: &mut Vec<[f32; 2]>) {
        if self.config.contracted {
            self.contracted_ray_segments(ray, out);
            return;
        }
        let (origin, direction, near, far) = (ray.origin, ray.direction, ray.near, ray.far);
        let b = self.config.bound;
        let r = self.config.resolution as i32;
        let h = self.cell_size();
        // The slab test: where the ray is inside the cube.
        let (mut t0, mut t1) = (near, far);
        for a in 0..3 {
            let (o, d) = (origin[a], direction[a]);
            if d == 0.0 {
                if o < -b || o > b {
                    return;
                }
                continue;
            }
            let (ta, tb) = ((-b - o) / d, (b - o) / d);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        // Nothing inside the cube (or a NaN from a degenerate ray).
        if t0.partial_cmp(&t1) != Some(std::cmp::Ordering::Less) {
            return;
        }
        let reach = 2.0 * ray.radius * t1.abs() / h;
        let occupied = match reach.ceil() {
            k if k >= 1.0 => &self.dilated[(k as usize).min(MAX_DILATION) - 1],
            _ => &self.occupied,
        };
        // The entry cell; a point on a face rounds to the cell inside through the clamp.
        let p = origin + direction * t0;
        let mut cell = [0i32; 3];
        let mut step = [0i32; 3];
        let mut t_max = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        for a in 0..3 {
            cell[a] = (((p[a] + b) / h).floor() as i32).clamp(0, r - 1);
            let d = direction[a];
            if d > 0.0 {
                step[a] = 1;
                t_max[a] = (-b + (cell[a] + 1) as f32 * h - origin[a]) / d;
                t_delta[a] = h / d;
            } else if d < 0.0 {
                step[a] = -1;
                t_max[a] = (-b + cell[a] as f32 * h - origin[a]) / d;
                t_delta[a] = -h / d;
            }
        }
        let mut t = t0;
        let mut open: Option<f32> = None;
        let res = r as usize;
        while t < t1 {
            let a = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
                0
            } else if t_max[1] <= t_max[2] {
                1
            } else {
                2
            };
            let t_next = t_max[a].min(t1).max(t);
            let occ = occupied[((cell[2] as usize * res) + cell[1] as usize) * res + cell[0] as usize];
            match (occ, open) {
                (true, None) => open = Some(t),
                (false, Some(s)) => {
                    if t > s {
                        out.push([s, t]);
                    }
                    open = None;
                }
                _ => {}
            }
            t = t_next;
            cell[a] += step[a];
            t_max[a] += t_delta[a];
            if cell[a] < 0 || cell[a] >= r {
                break;
            }
        }
        if let Some(s) = open
            && t > s
        {
            out.push([s, t]);
        }
    }
}

impl OccupancyGrid {
    /// [`ray_segments`](Self::ray_segments) in a contracted grid: the ray walked from `near` to
    /// `far` in `CONTRACTED_STEPS_PER_CELL · resolution` even steps of its normalised distance
    /// `s` ([`crate::contract::ray_distance_to_s`]), each step looked up at the contraction of its
    /// middle point, occupied steps joined into spans between their ends (`near` and `far` at the
    /// ends of the walk). The cone's footprint there, its radius `radius · t` scaled by the
    /// contraction across the ray from the origin (`(2 - 1/r)/r`), picks the dilation as in a
    /// world grid.
    fn contracted_ray_segments(&self, ray: &Ray, out: &mut Vec<[f32; 2]>) {
        use crate::contract::{contract, ray_distance_to_s, s_to_ray_distance};
        let (s0, s1) = (ray_distance_to_s(ray.near), ray_distance_to_s(ray.far));
        if s0.partial_cmp(&s1) != Some(std::cmp::Ordering::Less) {
            return;
        }
        let n = CONTRACTED_STEPS_PER_CELL * self.config.resolution;
        let ds = (s1 - s0) / n as f32;
        let edge = |k: usize| match k {
            0 => ray.near,
            k if k == n => ray.far,
            k => s_to_ray_distance(s0 + k as f32 * ds),
        };
        let (b, h, r) = (self.config.bound, self.cell_size(), self.config.resolution);
        let mut open: Option<f32> = None;
        for k in 0..n {
            let t = s_to_ray_distance(s0 + (k as f32 + 0.5) * ds);
            let x = ray.origin + ray.direction * t;
            let dist = x.length();
            let across = if dist > 1.0 { (2.0 - 1.0 / dist) / dist } else { 1.0 };
            let reach = (2.0 * ray.radius * t * across / h).ceil();
            let layer =
                if reach >= 1.0 { &self.dilated[(reach as usize).min(MAX_DILATION) - 1] } else { &self.occupied };
            let cell = (contract(x) + b) / h;
            let occ = cell.min_element() >= 0.0
                && cell.max_element() < r as f32
                && layer[(cell.z as usize * r + cell.y as usize) * r + cell.x as usize];
            match (occ, open) {
                (true, None) => open = Some(edge(k)),
                (false, Some(start)) => {
                    out.push([start, edge(k)]);
                    open = None;
                }
                _ => {}
            }
        }
        if let Some(start) = open {
            out.push([start, edge(n)]);
        }
    }
}
