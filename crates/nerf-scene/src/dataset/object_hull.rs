//! Where an object photographed alone stands: the bounding box of its visual hull, carved
//! from its silhouettes, and the depths along its cameras' rays that can meet it.
//!
//! A capture whose photos show nothing but the object (an alpha channel, or masks that
//! outline it, [`super::silhouette`]) says exactly where the object can be: inside every
//! camera's silhouette cone. A turntable object fills a few percent of the volume its camera
//! ring encloses, so a sampler spread over that whole volume (`nerf_scene`'s, sized for a
//! room) puts only a few dozen of its depths through the object; spread over the hull's
//! depths instead, every depth can land on it.
//!
//! Written by hand: carving a coarse voxel grid against binary silhouettes is a few loops;
//! no crate of the field does it for a set of calibrated photos.

use glam::DVec3;

use super::Dataset;
use nerf_core::camera::Camera;

/// Voxels along each side of the cube that is carved.
pub(crate) const HULL_RESOLUTION: usize = 64;

/// Half the side of the cube that is carved, in the normalised frame (the cameras stand at
/// most 1 from the centre, so an object they all look at lies inside).
pub(crate) const HULL_HALF_EXTENT: f64 = 1.0;

/// The carved box grows by this many voxels on every side: a voxel whose centre projects
/// just outside a silhouette may still hold some of the object.
pub(crate) const HULL_MARGIN_VOXELS: f64 = 2.0;

/// A voxel is part of the hull only when at least this fraction of the cameras see it (and
/// none outside its silhouette): below an object photographed from above, the voxels that
/// only the steepest views see project onto the object in those views and would otherwise
/// stretch the hull into a cone down to the carved cube's floor.
pub(crate) const HULL_SEEN_SHARE: f64 = 0.5;

/// A pixel belongs to the object where its transparency is below this.
pub(crate) const OBJECT_TRANSPARENCY: f32 = 0.5;

/// The cube a model of an object alone is fitted to is centred on the hull's box, its side
/// this many times the box's longest side.
pub(crate) const OBJECT_CUBE_SCALE: f64 = 1.1;

/// An axis-aligned box in the normalised frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct HullBox {
    /// The smallest corner.
    pub min: DVec3,
    /// The largest corner.
    pub max: DVec3,
}

impl HullBox {
    /// Distance from `point` to the nearest point of the box (0 inside it).
    pub(crate) fn nearest_distance(&self, point: DVec3) -> f64 {
        (point.clamp(self.min, self.max) - point).length()
    }

    /// Distance from `point` to the farthest corner of the box.
    pub(crate) fn farthest_distance(&self, point: DVec3) -> f64 {
        let far = DVec3::select(
            (point - self.min).cmpgt(self.max - point),
            self.min,
            self.max,
        );
        (far - point).length()
    }

    /// The cube `[min x, y, z, max x, y, z]` centred on the box, its side
    /// [`OBJECT_CUBE_SCALE`] times the box's longest side: a hash grid over it has cells of
    /// one size on every axis, all of them on the object's side of the hull.
    pub(crate) fn cube(&self) -> [f64; 6] {
        let centre = 0.5 * (self.min + self.max);
        let half = 0.5 * OBJECT_CUBE_SCALE * (self.max - self.min).max_element();
        let (lo, hi) = (centre - DVec3::splat(half), centre + DVec3::splat(half));
        [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z]
    }
}

/// Where an object photographed alone lies, for the sampler and the field to fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectFit {
    /// The cube round its visual hull (`HullBox::cube`).
    pub cube: [f64; 6],
    /// The sampler's depth range narrowed to the hull (`hull_depths`); `None` when the
    /// configured range is no wider.
    pub depths: Option<(f64, f64)>,
}

/// The bounding box of the visual hull of `dataset`'s silhouettes: the voxel centres of a
/// [`HULL_RESOLUTION`]³ grid over `[−HULL_HALF_EXTENT, HULL_HALF_EXTENT]³` that at least
/// [`HULL_SEEN_SHARE`] of the cameras see and that no camera sees outside its silhouette (a
/// pixel with transparency at least [`OBJECT_TRANSPARENCY`]), grown by
/// [`HULL_MARGIN_VOXELS`]. `None` unless every image has a transparency per pixel, some of it
/// background (opaque photos are no silhouettes), and a camera with pixel intrinsics (a
/// capture's); or when nothing is left (silhouettes that share no point).
pub(crate) fn silhouette_hull(dataset: &Dataset) -> Option<HullBox> {
    let (w, h) = (dataset.width, dataset.height);
    let background = |t: &Vec<f32>| t.iter().any(|&v| v >= OBJECT_TRANSPARENCY);
    if dataset.frames.is_empty()
        || dataset.transparency.len() != dataset.frames.len()
        || dataset
            .transparency
            .iter()
            .any(|t| t.len() != w * h || !background(t))
    {
        return None;
    }
    let cameras: Vec<_> = dataset
        .frames
        .iter()
        .map(|f| match &f.camera {
            Camera::Colmap(c) => Some(c),
            _ => None,
        })
        .collect::<Option<_>>()?;
    let n = HULL_RESOLUTION;
    let voxel = 2.0 * HULL_HALF_EXTENT / n as f64;
    let centre = |i: usize| -HULL_HALF_EXTENT + (i as f64 + 0.5) * voxel;
    let mut bounds: Option<HullBox> = None;
    for (ix, iy, iz) in
        (0..n).flat_map(|x| (0..n).flat_map(move |y| (0..n).map(move |z| (x, y, z))))
    {
        let p = DVec3::new(centre(ix), centre(iy), centre(iz));
        let mut seen = 0usize;
        let mut carved = false;
        for (camera, transparency) in cameras.iter().zip(&dataset.transparency) {
            let Some((u, v)) = camera.project(p) else {
                continue;
            };
            let (col, row) = (
                u * w as f64 / camera.size.0 as f64,
                v * h as f64 / camera.size.1 as f64,
            );
            if !(col >= 0.0 && row >= 0.0 && col < w as f64 && row < h as f64) {
                continue;
            }
            seen += 1;
            if transparency[row as usize * w + col as usize] >= OBJECT_TRANSPARENCY {
                carved = true;
                break;
            }
        }
        if !carved && seen as f64 >= HULL_SEEN_SHARE * cameras.len() as f64 {
            bounds = Some(match bounds {
                None => HullBox { min: p, max: p },
                Some(b) => HullBox {
                    min: b.min.min(p),
                    max: b.max.max(p),
                },
            });
        }
    }
    let grow = DVec3::splat((HULL_MARGIN_VOXELS + 0.5) * voxel);
    bounds.map(|b| HullBox {
        min: b.min - grow,
        max: b.max + grow,
    })
}

/// The depths along rays from cameras at `centres` that can meet `hull`: from the nearest
/// camera's distance to the box (0 for a camera inside it) to the farthest camera's distance
/// to the box's farthest corner.
pub(crate) fn hull_depths(hull: &HullBox, centres: &[DVec3]) -> Option<(f64, f64)> {
    let near = centres
        .iter()
        .map(|&c| hull.nearest_distance(c))
        .fold(f64::INFINITY, f64::min);
    let far = centres
        .iter()
        .map(|&c| hull.farthest_distance(c))
        .fold(0.0, f64::max);
    (near.is_finite() && far > near).then_some((near, far))
}

/// The cube and the depths ([`ObjectFit`]) of the object `dataset`'s silhouettes outline
/// (`silhouette_hull`): the depths are the sampler's configured range `(min_depth,
/// max_depth)` narrowed to those at which the cameras can meet the hull (`hull_depths`).
/// `None` when the photos do not outline an object.
pub fn object_fit(dataset: &Dataset, (min_depth, max_depth): (f64, f64)) -> Option<ObjectFit> {
    let hull = silhouette_hull(dataset)?;
    let centres: Vec<DVec3> = dataset.frames.iter().map(|f| f.camera.center()).collect();
    let depths = hull_depths(&hull, &centres).and_then(|(near, far)| {
        let (near, far) = (near.max(min_depth), far.min(max_depth));
        (far > near && (near > min_depth || far < max_depth)).then_some((near, far))
    });
    Some(ObjectFit {
        cube: hull.cube(),
        depths,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The narrowed depth range of [`object_fit`], as training takes it.
    fn object_depths(dataset: &Dataset, range: (f64, f64)) -> Option<(f64, f64)> {
        object_fit(dataset, range)?.depths
    }
    use crate::dataset::Frame;
    use nerf_core::camera::{ColmapCamera, ColmapPose};
    use nerf_core::image::RgbImage;

    /// A pinhole camera at `eye` looking at the origin, world +z up (OpenCV axes: x right,
    /// y down, z forward), `size × size` pixels with a 60° field of view.
    fn camera_at(eye: DVec3, size: usize) -> ColmapCamera {
        let forward = (-eye).normalize();
        let right = forward.cross(DVec3::Z).normalize();
        let down = forward.cross(right);
        let rows = [right.to_array(), down.to_array(), forward.to_array()];
        let rotation = glam::DMat3::from_cols_array_2d(&rows).transpose();
        let translation = -(rotation * eye);
        let pose = ColmapPose::from_matrix(rows, translation.to_array());
        let f = 0.5 * size as f64 / (30f64.to_radians()).tan();
        let c = 0.5 * size as f64;
        ColmapCamera::from_colmap("SIMPLE_PINHOLE", &[f, c, c], (size, size), pose).unwrap()
    }

    /// A ring of twelve cameras at distance 1 round a ball of radius `r` at `centre`, and two
    /// looking down on it from nearly straight above, each photo's
    /// transparency 0 on the ball's silhouette and 1 elsewhere (rendered by casting a ray
    /// through every pixel).
    fn ball_dataset(r: f64, centre: DVec3, size: usize) -> Dataset {
        let ring = (0..12).map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 12.0;
            DVec3::new(a.cos(), a.sin(), 0.3)
        });
        let above = [DVec3::new(0.05, 0.0, 1.0), DVec3::new(-0.05, 0.02, 1.0)];
        let cameras: Vec<ColmapCamera> = ring
            .chain(above)
            .map(|eye| camera_at(eye.normalize(), size))
            .collect();
        let transparency = cameras
            .iter()
            .map(|c| {
                (0..size * size)
                    .map(|p| {
                        let (u, v) = ((p % size) as f64 + 0.5, (p / size) as f64 + 0.5);
                        let (o, d) = c.ray_through_pixel(u, v);
                        let closest = o + d * (centre - o).dot(d);
                        if (closest - centre).length() <= r {
                            0.0
                        } else {
                            1.0
                        }
                    })
                    .collect()
            })
            .collect();
        Dataset {
            frames: cameras
                .into_iter()
                .map(|c| Frame {
                    file_path: "ball.png".into(),
                    camera: c.into(),
                    mask_path: None,
                })
                .collect(),
            images: vec![RgbImage::new(size, size, vec![0.0; 3 * size * size]).unwrap(); 14],
            transparency,
            width: size,
            height: size,
            masks: Vec::new(),
            normalisation: None,
            capture: None,
        }
    }

    #[test]
    fn the_hull_of_a_ball_holds_the_ball_and_little_more() {
        let (r, centre) = (0.15, DVec3::new(0.1, -0.05, 0.0));
        let dataset = ball_dataset(r, centre, 64);
        let hull = silhouette_hull(&dataset).expect("a hull");
        let voxel = 2.0 * HULL_HALF_EXTENT / HULL_RESOLUTION as f64;
        // Every side holds the ball and stays within the margin and a voxel of it (in z the
        // ring's cones, 17° above the ball's equator, add a little more): the cone below the
        // ball that only the two views from above see is not part of it.
        for k in 0..3 {
            assert!(
                hull.min[k] <= centre[k] - r && hull.max[k] >= centre[k] + r,
                "{hull:?}"
            );
            let slack = (HULL_MARGIN_VOXELS + 2.5) * voxel + if k == 2 { 0.05 } else { 0.0 };
            assert!(hull.min[k] >= centre[k] - r - slack, "{hull:?}");
            assert!(hull.max[k] <= centre[k] + r + slack, "{hull:?}");
        }
    }

    #[test]
    fn the_depths_run_from_the_nearest_camera_to_the_far_side() {
        let hull = HullBox {
            min: DVec3::splat(-0.2),
            max: DVec3::splat(0.2),
        };
        let centres = [DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, -2.0, 0.0)];
        let (near, far) = hull_depths(&hull, &centres).unwrap();
        assert!((near - 0.8).abs() < 1e-12);
        let corner = DVec3::new(-0.2, 0.2, 0.2) - DVec3::new(0.0, -2.0, 0.0);
        assert!((far - corner.length()).abs() < 1e-12);
        // A camera inside the box sees it from depth 0.
        assert_eq!(hull_depths(&hull, &[DVec3::ZERO]).unwrap().0, 0.0);
        assert!(hull_depths(&hull, &[]).is_none());
    }

    #[test]
    fn the_sampler_narrows_only_to_an_outlined_object() {
        let mut dataset = ball_dataset(0.15, DVec3::ZERO, 48);
        let (near, far) = object_depths(&dataset, (0.02, 2.8)).expect("narrowed");
        // The cube holds the ball, centred on it, a little more than its hull's box.
        let cube = object_fit(&dataset, (0.02, 2.8)).unwrap().cube;
        let side = cube[3] - cube[0];
        for k in 0..3 {
            assert!((cube[k + 3] - cube[k] - side).abs() < 1e-12, "{cube:?}");
            assert!(cube[k] < -0.15 && cube[k + 3] > 0.15, "{cube:?}");
        }
        assert!(side < 0.6, "{cube:?}");
        assert!(
            near > 0.6 && near < 0.85 && far > 1.15 && far < 1.4,
            "{near} {far}"
        );
        // A range already inside the hull's is kept as it is.
        assert!(object_depths(&dataset, (0.9, 1.1)).is_none());
        // An opaque photo (all transparency 0, as the loader gives photos without alpha, or
        // none): not an object alone.
        dataset.transparency[3] = vec![0.0; 48 * 48];
        assert!(object_depths(&dataset, (0.02, 2.8)).is_none());
        dataset.transparency[3].clear();
        assert!(object_depths(&dataset, (0.02, 2.8)).is_none());
    }
}
