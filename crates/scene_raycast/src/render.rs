//! A ray-cast camera renderer: Lambert shading with sun shadows, sky gradient,
//! an infinite ground plane beyond the scene, exponential haze and sensor noise.
//!
//! The camera is described only by a per-pixel table of unit rays in its optical
//! frame C (z forward, x right, y down), so any lens model (OpenCV distortion
//! included) is handled by whoever builds the table. Colours are linear RGB in
//! [0, 1]; the output is gamma-encoded 8-bit RGB.

use nalgebra::{Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::error::RaycastError;
use crate::scene::{check_directions, check_finite_rows, unit, Hit, Scene};

/// Shadow rays start this far (m) off the surface, along its normal, so that
/// they do not hit the surface they leave.
pub const SHADOW_OFFSET: f64 = 2e-3;
/// Display gamma of the 8-bit output.
const GAMMA: f64 = 2.2;

/// Lighting, atmosphere and sensor settings of one render.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// Unit vector from the scene toward the sun, W.
    pub sun_direction: Vector3<f64>,
    /// Sun irradiance colour (linear RGB, a surface facing the sun gets albedo * this).
    pub sun_color: [f64; 3],
    /// Ambient (sky) irradiance colour, linear RGB.
    pub ambient: [f64; 3],
    /// Sky colour straight up, linear RGB.
    pub sky_zenith: [f64; 3],
    /// Sky colour at the horizon; also the colour haze fades toward.
    pub sky_horizon: [f64; 3],
    /// Albedo of the infinite ground plane z = `ground_height` beyond the scene.
    pub ground_color: [f64; 3],
    /// Height of that plane in W, m.
    pub ground_height: f64,
    /// Haze extinction coefficient, 1/m (0 = clear air).
    pub haze_density: f64,
    /// Standard deviation of the additive Gaussian image noise, 8-bit counts.
    pub noise_sigma: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// Cast a shadow ray toward the sun from every lit surface point.
    pub shadows: bool,
    /// Farthest geometry seen, m (> 0, may be infinite).
    pub max_range: f64,
}

impl Default for Lighting {
    fn default() -> Self {
        Self {
            sun_direction: Vector3::new(0.5, 0.3, 0.81).normalize(),
            sun_color: [1.0, 0.97, 0.9],
            ambient: [0.35, 0.38, 0.45],
            sky_zenith: [0.25, 0.45, 0.85],
            sky_horizon: [0.75, 0.82, 0.92],
            ground_color: [0.3, 0.35, 0.22],
            ground_height: 0.0,
            haze_density: 0.0,
            noise_sigma: 0.0,
            seed: 0,
            shadows: true,
            max_range: 1000.0,
        }
    }
}

impl Lighting {
    fn validate(&self) -> Result<Vector3<f64>, RaycastError> {
        let sun_norm = self.sun_direction.norm();
        if !(sun_norm.is_finite() && sun_norm > 0.0) {
            return Err(RaycastError::BadParameter {
                name: "sun_direction",
                reason: "must be a finite non-zero vector",
                value: sun_norm,
            });
        }
        let colours = [
            ("sun_color", self.sun_color),
            ("ambient", self.ambient),
            ("sky_zenith", self.sky_zenith),
            ("sky_horizon", self.sky_horizon),
            ("ground_color", self.ground_color),
        ];
        for (name, colour) in colours {
            if let Some(&bad) = colour.iter().find(|c| !(c.is_finite() && **c >= 0.0)) {
                return Err(RaycastError::BadParameter {
                    name,
                    reason: "components must be finite and >= 0",
                    value: bad,
                });
            }
        }
        let scalars = [
            ("haze_density", self.haze_density),
            ("noise_sigma", self.noise_sigma),
        ];
        for (name, value) in scalars {
            if !(value.is_finite() && value >= 0.0) {
                return Err(RaycastError::BadParameter {
                    name,
                    reason: "must be finite and >= 0",
                    value,
                });
            }
        }
        if !self.ground_height.is_finite() {
            return Err(RaycastError::BadParameter {
                name: "ground_height",
                reason: "must be finite",
                value: self.ground_height,
            });
        }
        crate::scene::validate_max_range(self.max_range)?;
        Ok(self.sun_direction / sun_norm)
    }
}

/// A rendered frame: row-major, `width * height` pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// Gamma-encoded RGB, 3 bytes per pixel.
    pub rgb: Vec<u8>,
    /// Instance id seen by each pixel, -1 for sky and the ground beyond the scene.
    pub instance_id: Vec<i32>,
    /// Distance along the pixel's ray to the scene, m (infinite where id is -1).
    pub depth: Vec<f32>,
}

/// Renders the scene from a camera at `position` (W, m) with orientation
/// `rotation_w_c` (maps C vectors to W), through `rays_c` (one ray per pixel
/// in C, row-major, need not be unit), into a `width` x `height` image.
/// `albedo[id]` is the linear RGB colour of instance `id` (ids beyond the table
/// are mid-grey).
#[allow(clippy::too_many_arguments)]
pub fn render(
    scene: &Scene,
    rotation_w_c: &Matrix3<f64>,
    position: &Point3<f64>,
    rays_c: &[[f64; 3]],
    width: usize,
    height: usize,
    albedo: &[[f64; 3]],
    lighting: &Lighting,
) -> Result<Image, RaycastError> {
    if width == 0 || height == 0 {
        return Err(RaycastError::BadParameter {
            name: "width/height",
            reason: "image size must be at least 1x1",
            value: (width.min(height)) as f64,
        });
    }
    let n_pixels = width
        .checked_mul(height)
        .ok_or(RaycastError::BadParameter {
            name: "width/height",
            reason: "image too large",
            value: width as f64,
        })?;
    if rays_c.len() != n_pixels {
        return Err(RaycastError::LengthMismatch {
            name: "rays_c",
            expected: n_pixels,
            got: rays_c.len(),
        });
    }
    if !(rotation_w_c.iter().all(|c| c.is_finite())
        && (rotation_w_c.transpose() * rotation_w_c - Matrix3::identity()).norm() < 1e-6
        && rotation_w_c.determinant() > 0.0)
    {
        return Err(RaycastError::BadParameter {
            name: "T_w_c",
            reason: "rotation part must be a proper rotation matrix",
            value: rotation_w_c.determinant(),
        });
    }
    check_finite_rows("position", &[[position.x, position.y, position.z]])?;
    if let Some(&bad) = albedo
        .iter()
        .flatten()
        .find(|c| !(c.is_finite() && **c >= 0.0))
    {
        return Err(RaycastError::BadParameter {
            name: "albedo",
            reason: "components must be finite and >= 0",
            value: bad,
        });
    }
    let sun = lighting.validate()?;
    check_directions("rays_c", rays_c)?;

    let gamma = GammaEncoder::new();
    let mut rgb = vec![0u8; n_pixels * 3];
    let mut ids = vec![-1i32; n_pixels];
    let mut depth = vec![f32::INFINITY; n_pixels];
    let camera = Camera {
        scene,
        rotation_w_c,
        position,
        rays_c,
        width,
        albedo,
        lighting,
        sun,
    };
    rgb.par_chunks_mut(width * 3 * TILE_ROWS)
        .zip(ids.par_chunks_mut(width * TILE_ROWS))
        .zip(depth.par_chunks_mut(width * TILE_ROWS))
        .enumerate()
        .try_for_each(|(band, ((rgb_band, id_band), depth_band))| {
            let first_row = band * TILE_ROWS;
            let rows = id_band.len() / width;
            // One generator per row keeps the noise independent of the thread count
            // and of the tiling: each row's pixels draw from it left to right.
            let mut rngs: Vec<Pcg64Mcg> = (first_row..first_row + rows)
                .map(|row| row_rng(lighting.seed, row))
                .collect();
            let mut tile = Tile::default();
            for first_col in (0..width).step_by(TILE_COLS) {
                let cols = first_col..(first_col + TILE_COLS).min(width);
                camera.trace(&mut tile, first_row..first_row + rows, cols.clone())?;
                for (k, (colour, id, dist)) in tile.shaded.iter().enumerate() {
                    let (row, col) = (k / cols.len(), cols.start + k % cols.len());
                    let pixel = row * width + col;
                    id_band[pixel] = *id;
                    depth_band[pixel] = *dist as f32;
                    for (c, byte) in rgb_band[pixel * 3..pixel * 3 + 3].iter_mut().enumerate() {
                        let noise = if lighting.noise_sigma > 0.0 {
                            lighting.noise_sigma * rngs[row].sample::<f64, _>(StandardNormal)
                        } else {
                            0.0
                        };
                        *byte = gamma.encode(colour[c], noise);
                    }
                }
            }
            Ok::<(), RaycastError>(())
        })?;
    Ok(Image {
        width,
        height,
        rgb,
        instance_id: ids,
        depth,
    })
}

/// Camera rays are cast in tiles of this many rows by [`TILE_COLS`] columns, one
/// packet each ([`Scene::cast_packet`]): neighbouring pixels visit the same BVH
/// nodes, and so do the shadow rays of their surface points.
const TILE_ROWS: usize = 8;
/// See [`TILE_ROWS`].
const TILE_COLS: usize = 8;

/// The noise generator of image row `row`.
fn row_rng(seed: u64, row: usize) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(
        seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(row as u64),
    )
}

/// One render's camera, scene and light, validated.
struct Camera<'a> {
    scene: &'a Scene,
    rotation_w_c: &'a Matrix3<f64>,
    position: &'a Point3<f64>,
    rays_c: &'a [[f64; 3]],
    width: usize,
    albedo: &'a [[f64; 3]],
    lighting: &'a Lighting,
    /// Unit vector toward the sun, W.
    sun: Vector3<f64>,
}

/// Scratch of one tile, kept from tile to tile.
#[derive(Default)]
struct Tile {
    origins: Vec<Point3<f64>>,
    directions: Vec<Vector3<f64>>,
    hits: Vec<Option<Hit>>,
    /// Sun-facing share of the direct light at each pixel's surface.
    direct: Vec<f64>,
    shadow_origins: Vec<Point3<f64>>,
    shadow_directions: Vec<Vector3<f64>>,
    /// Pixel (tile index) of each shadow ray.
    shadow_pixels: Vec<usize>,
    shadowed: Vec<bool>,
    /// Colour (linear RGB), instance id and distance of each pixel, row-major.
    shaded: Vec<([f64; 3], i32, f64)>,
}

impl Camera<'_> {
    /// Shades the pixels `rows` x `cols` into `tile.shaded` (row-major): their
    /// rays cast as one packet, then the shadow rays of their lit surfaces as one.
    fn trace(
        &self,
        tile: &mut Tile,
        rows: std::ops::Range<usize>,
        cols: std::ops::Range<usize>,
    ) -> Result<(), RaycastError> {
        let lighting = self.lighting;
        tile.directions.clear();
        for row in rows {
            for col in cols.clone() {
                let ray = &self.rays_c[row * self.width + col];
                tile.directions.push(self.rotation_w_c * unit(ray));
            }
        }
        let n = tile.directions.len();
        tile.origins.clear();
        tile.origins.resize(n, *self.position);
        tile.hits.clear();
        tile.hits.resize(n, None);
        self.scene.cast_packet(
            &tile.origins,
            &tile.directions,
            lighting.max_range,
            &mut tile.hits,
        )?;
        tile.direct.clear();
        tile.shadow_origins.clear();
        tile.shadow_pixels.clear();
        for (k, (hit, dir)) in tile.hits.iter().zip(&tile.directions).enumerate() {
            let direct = match hit {
                Some(hit) => {
                    let normal = facing(hit, dir);
                    let direct = normal.dot(&self.sun).max(0.0);
                    if direct > 0.0 && lighting.shadows {
                        tile.shadow_origins
                            .push(self.position + dir * hit.distance + normal * SHADOW_OFFSET);
                        tile.shadow_pixels.push(k);
                    }
                    direct
                }
                None => 0.0,
            };
            tile.direct.push(direct);
        }
        let shadows = tile.shadow_origins.len();
        tile.shadow_directions.clear();
        tile.shadow_directions.resize(shadows, self.sun);
        tile.shadowed.clear();
        tile.shadowed.resize(shadows, false);
        self.scene.occluded_packet(
            &tile.shadow_origins,
            &tile.shadow_directions,
            lighting.max_range,
            &mut tile.shadowed,
        )?;
        for (&pixel, &shadowed) in tile.shadow_pixels.iter().zip(&tile.shadowed) {
            if shadowed {
                tile.direct[pixel] = 0.0;
            }
        }
        tile.shaded.clear();
        for ((hit, dir), &direct) in tile.hits.iter().zip(&tile.directions).zip(&tile.direct) {
            tile.shaded.push(shade(
                hit.as_ref(),
                direct,
                self.position,
                dir,
                self.albedo,
                lighting,
                &self.sun,
            ));
        }
        Ok(())
    }
}

/// Entries of [`GammaEncoder`]'s table over [0, 1].
const GAMMA_TABLE: usize = 4096;
/// Below this linear value the table is not used: the curve's slope is unbounded at 0.
const GAMMA_TABLE_FROM: f64 = 1.0 / 256.0;
/// The table's interpolation error above [`GAMMA_TABLE_FROM`] is under 3e-3 counts
/// (h^2 / 8 max |f''|); within this many counts of a rounding boundary the exact
/// curve decides, so the bytes are those of `powf` everywhere.
const GAMMA_TABLE_GUARD: f64 = 0.01;

/// The 8-bit gamma encoding round(255 c^(1/GAMMA) + noise), clamped, with the same
/// bytes as the direct formula but mostly without its `powf`: a linearly
/// interpolated table, and the exact curve only for dark values and for sums near
/// a rounding boundary.
struct GammaEncoder {
    table: Vec<f64>,
}

impl GammaEncoder {
    fn new() -> Self {
        Self {
            table: (0..=GAMMA_TABLE)
                .map(|i| exact_gamma(i as f64 / GAMMA_TABLE as f64))
                .collect(),
        }
    }

    /// The byte of linear value `linear` (clamped to [0, 1]) plus `noise` counts.
    #[inline]
    fn encode(&self, linear: f64, noise: f64) -> u8 {
        let c = linear.clamp(0.0, 1.0);
        let byte = |encoded: f64| (encoded + noise).round().clamp(0.0, 255.0) as u8;
        if c < GAMMA_TABLE_FROM {
            return byte(exact_gamma(c));
        }
        let x = c * GAMMA_TABLE as f64;
        let i = (x as usize).min(GAMMA_TABLE - 1);
        let f = x - i as f64;
        let approx = self.table[i] + f * (self.table[i + 1] - self.table[i]);
        let sum = approx + noise;
        if ((sum - sum.floor()) - 0.5).abs() < GAMMA_TABLE_GUARD {
            return byte(exact_gamma(c));
        }
        byte(approx)
    }
}

/// 255 c^(1/GAMMA): the encoded value before rounding.
fn exact_gamma(c: f64) -> f64 {
    255.0 * c.powf(1.0 / GAMMA)
}

/// The normal of the surface `hit` facing the ray `dir`: thin open surfaces are
/// lit from whichever side is seen.
fn facing(hit: &Hit, dir: &Vector3<f64>) -> Vector3<f64> {
    if hit.normal.dot(dir) > 0.0 {
        -hit.normal
    } else {
        hit.normal
    }
}

/// Colour (linear RGB), instance id and distance seen along one unit ray `dir` in
/// W from `origin`, given what it hit and the sun's direct share there (the cosine
/// of the sun on the [`facing`] normal, 0 in shadow).
fn shade(
    hit: Option<&Hit>,
    direct: f64,
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    albedo: &[[f64; 3]],
    lighting: &Lighting,
    sun: &Vector3<f64>,
) -> ([f64; 3], i32, f64) {
    let haze = |colour: [f64; 3], distance: f64| -> [f64; 3] {
        let transmission = (-lighting.haze_density * distance).exp();
        std::array::from_fn(|k| {
            colour[k] * transmission + lighting.sky_horizon[k] * (1.0 - transmission)
        })
    };
    let sun_elevation_factor = sun.z.max(0.0);
    if let Some(hit) = hit {
        let base = usize::try_from(hit.instance_id)
            .ok()
            .and_then(|i| albedo.get(i))
            .copied()
            .unwrap_or([0.5; 3]);
        let lit = std::array::from_fn(|k| {
            base[k] * (lighting.ambient[k] + lighting.sun_color[k] * direct)
        });
        return (haze(lit, hit.distance), hit.instance_id, hit.distance);
    }
    let height_above_ground = origin.z - lighting.ground_height;
    if dir.z < 0.0 && height_above_ground > 0.0 {
        // The ground beyond the scene: flat, lit, never shadowed, hazed by distance.
        let distance = height_above_ground / -dir.z;
        let lit = std::array::from_fn(|k| {
            lighting.ground_color[k]
                * (lighting.ambient[k] + lighting.sun_color[k] * sun_elevation_factor)
        });
        return (haze(lit, distance), -1, f64::INFINITY);
    }
    // Sky: horizon colour blending into the zenith colour with elevation.
    let up = dir.z.clamp(0.0, 1.0).sqrt();
    let sky =
        std::array::from_fn(|k| lighting.sky_horizon[k] * (1.0 - up) + lighting.sky_zenith[k] * up);
    (sky, -1, f64::INFINITY)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2x2 floor at z = 0 and a camera 10 m above it looking straight down.
    fn floor() -> Result<Scene, RaycastError> {
        let h = 100.0;
        Scene::new(
            &[[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]],
            &[[0, 1, 2], [0, 2, 3]],
            &[0, 0],
        )
    }

    fn down() -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
    }

    fn encode(linear: f64) -> u8 {
        (255.0 * linear.powf(1.0 / GAMMA)).round() as u8
    }

    #[test]
    fn lambert_with_haze_matches_the_formula() -> Result<(), RaycastError> {
        let scene = floor()?;
        let lighting = Lighting {
            sun_direction: Vector3::new(0.0, 0.6, 0.8),
            sun_color: [1.0, 1.0, 1.0],
            ambient: [0.2, 0.2, 0.2],
            haze_density: 0.05,
            sky_horizon: [0.9, 0.9, 0.9],
            ..Lighting::default()
        };
        let img = render(
            &scene,
            &down(),
            &Point3::new(0.0, 0.0, 10.0),
            &[[0.0, 0.0, 1.0]],
            1,
            1,
            &[[0.5, 0.5, 0.5]],
            &lighting,
        )?;
        let lit = 0.5 * (0.2 + 0.8);
        let tr = (-0.05f64 * 10.0).exp();
        let expected = encode(lit * tr + 0.9 * (1.0 - tr));
        assert_eq!(img.rgb, vec![expected; 3]);
        assert_eq!(img.instance_id, vec![0]);
        assert!((img.depth[0] - 10.0).abs() < 1e-5);
        Ok(())
    }

    #[test]
    fn sky_and_far_ground_beyond_the_scene() -> Result<(), RaycastError> {
        let scene = floor()?;
        let lighting = Lighting {
            sun_direction: Vector3::z(),
            noise_sigma: 0.0,
            ..Lighting::default()
        };
        // Horizontal-ish rays from 50 m up: downward beyond the 100 m floor -> far ground;
        // upward -> sky between horizon and zenith.
        let rays = [[1.0, 0.0, -0.2], [1.0, 0.0, 0.5]]; // C = W here
        let img = render(
            &scene,
            &Matrix3::identity(),
            &Point3::new(0.0, 0.0, 50.0),
            &rays,
            2,
            1,
            &[],
            &lighting,
        )?;
        assert_eq!(img.instance_id, vec![-1, -1]);
        let g = lighting.ground_color[0] * (lighting.ambient[0] + lighting.sun_color[0]);
        assert_eq!(img.rgb[0], encode(g));
        let up = (0.5f64 / 1.25f64.sqrt()).sqrt();
        let sky = lighting.sky_horizon[2] * (1.0 - up) + lighting.sky_zenith[2] * up;
        assert_eq!(img.rgb[5], encode(sky));
        Ok(())
    }

    #[test]
    fn gamma_table_gives_the_bytes_of_the_exact_curve() {
        let gamma = GammaEncoder::new();
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        for i in 0..200_000 {
            let c = if i < 100_000 {
                i as f64 / 100_000.0
            } else {
                rng.random::<f64>() * 1.2 - 0.1
            };
            for noise in [0.0, 3.0 * rng.sample::<f64, _>(StandardNormal)] {
                let direct = (exact_gamma(c.clamp(0.0, 1.0)) + noise)
                    .round()
                    .clamp(0.0, 255.0) as u8;
                assert_eq!(gamma.encode(c, noise), direct, "c = {c}, noise = {noise}");
            }
        }
    }

    #[test]
    fn bad_arguments_are_named() -> Result<(), RaycastError> {
        let scene = floor()?;
        let l = Lighting::default();
        let p = Point3::new(0.0, 0.0, 5.0);
        let r = |w, h, rays: &[[f64; 3]], rot: &Matrix3<f64>, l: &Lighting| {
            render(&scene, rot, &p, rays, w, h, &[], l)
        };
        let name =
            |e: Result<Image, RaycastError>| e.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(name(r(0, 1, &[], &down(), &l)).starts_with("width/height"));
        assert!(name(r(2, 1, &[[0.0, 0.0, 1.0]], &down(), &l)).starts_with("rays_c"));
        assert!(name(r(1, 1, &[[0.0, 0.0, 0.0]], &down(), &l)).starts_with("rays_c"));
        assert!(name(r(1, 1, &[[0.0, 0.0, 1.0]], &(down() * 2.0), &l)).starts_with("T_w_c"));
        let bad = Lighting {
            haze_density: -1.0,
            ..Lighting::default()
        };
        assert!(name(r(1, 1, &[[0.0, 0.0, 1.0]], &down(), &bad)).starts_with("haze_density"));
        let bad = Lighting {
            sun_direction: Vector3::zeros(),
            ..Lighting::default()
        };
        assert!(name(r(1, 1, &[[0.0, 0.0, 1.0]], &down(), &bad)).starts_with("sun_direction"));
        Ok(())
    }
}
