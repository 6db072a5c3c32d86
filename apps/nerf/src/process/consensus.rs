//! Which of several reconstructions of one set of photos to trust. Incremental structure from
//! motion draws its RANSAC samples at random: on photos with few features, most runs agree to
//! a fraction of a percent while one now and then places a camera wrongly (a view flipped to
//! its mirror pose, or a bent stretch of cameras), with nothing in the run's own statistics
//! (reprojection error, track lengths) to tell. Runs with different seeds make errors in
//! different places, so the run that agrees best with the others is the one to keep, and a
//! camera that most other runs place elsewhere is one to leave out.
//!
//! Agreement between two runs is measured on the images both registered: the second run's
//! centres are aligned to the first's by the least-squares similarity
//! (`nerf::core::camera::alignment::align_centres`), re-fitted without the cameras far
//! off it so that a flipped camera does not pull the rest, and each image's centre distance is
//! taken as a fraction of the first run's camera spread (the root-mean-square distance of its
//! centres from their mean).

use std::collections::BTreeMap;

use glam::{DMat3, DVec3};

use nerf::core::camera::alignment::{align_centres, spread, CameraPair};

/// Camera centres of one reconstruction, by image name.
pub(crate) type Centres = BTreeMap<String, DVec3>;

/// Fewest shared images two runs are compared on (a similarity needs three centres).
const MIN_SHARED: usize = 3;

/// What [`consensus`] chose.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Consensus {
    /// Index of the chosen run.
    pub chosen: usize,
    /// Per run: the mean over the other comparable runs of the largest centre disagreement
    /// with them (fractions of the camera spread); `None` for a run not compared (too few
    /// images registered, or no other comparable run).
    pub scores: Vec<Option<f64>>,
    /// Images of the chosen run that more than half of the other compared runs place more
    /// than `outlier` (a fraction of the spread) away, with their median disagreement,
    /// largest first; empty when the runs disagree on most cameras (see `split`).
    pub outliers: Vec<(String, f64)>,
    /// The compared runs place half or more of the chosen run's cameras apart: they disagree
    /// as wholes (a bent or differently scaled reconstruction), so no single camera can be
    /// named as the misplaced one, and none is.
    pub split: bool,
}

/// Per image both `reference` and `other` hold (in name order), its centre disagreement:
/// `other` aligned to `reference` by the least-squares similarity of the shared centres,
/// distances as fractions of `reference`'s spread over the shared images. `None` when they
/// share fewer than `MIN_SHARED` images or `reference`'s shared centres coincide.
pub(crate) fn disagreement(reference: &Centres, other: &Centres) -> Option<Vec<(String, f64)>> {
    let shared: Vec<(&String, DVec3, DVec3)> = reference
        .iter()
        .filter_map(|(name, c)| other.get(name).map(|o| (name, *c, *o)))
        .collect();
    if shared.len() < MIN_SHARED {
        return None;
    }
    let size = spread(&shared.iter().map(|s| s.1).collect::<Vec<_>>());
    if !(size > 0.0 && size.is_finite()) {
        return None;
    }
    let pairs: Vec<CameraPair> = shared
        .iter()
        .map(|&(_, true_centre, centre)| CameraPair {
            true_rotation: DMat3::IDENTITY,
            true_centre,
            rotation: DMat3::IDENTITY,
            centre,
        })
        .collect();
    let errors = robust_centre_errors(&pairs);
    Some(
        shared
            .iter()
            .zip(errors)
            .map(|(s, e)| (s.0.clone(), e / size))
            .collect(),
    )
}

/// Rounds of [`robust_centre_errors`]' re-alignment.
const ROBUST_ROUNDS: usize = 3;

/// Per pair, the centre error after a least-squares similarity that is not pulled by a few
/// misplaced cameras: aligned on all, then [`ROBUST_ROUNDS`] times re-aligned on the cameras
/// whose error is at most three times the median (at least half of them), each camera's
/// error taken under the last alignment.
fn robust_centre_errors(pairs: &[CameraPair]) -> Vec<f64> {
    let mut errors = align_centres(pairs).centre_errors;
    for _ in 0..ROBUST_ROUNDS {
        let mut sorted = errors.clone();
        sorted.sort_by(f64::total_cmp);
        let limit = 3.0 * sorted[sorted.len() / 2];
        let kept: Vec<CameraPair> = pairs
            .iter()
            .zip(&errors)
            .filter(|(_, &e)| e <= limit)
            .map(|(p, _)| *p)
            .collect();
        if kept.len() < MIN_SHARED || kept.len() == pairs.len() {
            break;
        }
        let fit = align_centres(&kept);
        errors = pairs
            .iter()
            .map(|p| (fit.scale * (fit.rotation * p.centre) + fit.shift).distance(p.true_centre))
            .collect();
    }
    errors
}

/// The run of `runs` to keep: among the runs that registered at least `min_fraction` of the
/// most any run registered, the one whose largest disagreement with each other such run is
/// smallest on average; with its images that most other runs place more than `outlier` away
/// (see [`Consensus`]). A single comparable run is chosen as it is. Cameras are named
/// outliers only when they are fewer than half of the chosen run's: a misplaced camera stands
/// out against the rest agreeing, while runs that disagree nearly everywhere (two runs, one of
/// them bent) give no majority to tell which cameras are wrong, and leaving all of them out
/// would leave nothing. `None` when no run registered any image.
pub(crate) fn consensus(runs: &[Centres], min_fraction: f64, outlier: f64) -> Option<Consensus> {
    let most = runs.iter().map(BTreeMap::len).max().filter(|&m| m > 0)?;
    let comparable: Vec<usize> = (0..runs.len())
        .filter(|&i| runs[i].len() as f64 >= min_fraction * most as f64)
        .collect();
    let mut scores = vec![None; runs.len()];
    let mut per_run: Vec<Vec<Vec<(String, f64)>>> = vec![Vec::new(); runs.len()];
    for &i in &comparable {
        let against: Vec<Vec<(String, f64)>> = comparable
            .iter()
            .filter(|&&j| j != i)
            .filter_map(|&j| disagreement(&runs[i], &runs[j]))
            .collect();
        if !against.is_empty() {
            let largest = |d: &Vec<(String, f64)>| d.iter().map(|e| e.1).fold(0.0, f64::max);
            scores[i] = Some(against.iter().map(largest).sum::<f64>() / against.len() as f64);
        }
        per_run[i] = against;
    }
    let chosen = (0..runs.len())
        .filter(|&i| scores[i].is_some())
        .min_by(|&a, &b| {
            scores[a]
                .unwrap_or(0.0)
                .total_cmp(&scores[b].unwrap_or(0.0))
        })
        .or_else(|| comparable.first().copied())?;
    let mut outliers: Vec<(String, f64)> = runs[chosen]
        .keys()
        .filter_map(|name| {
            let mut seen: Vec<f64> = per_run[chosen]
                .iter()
                .filter_map(|d| d.iter().find(|e| &e.0 == name).map(|e| e.1))
                .collect();
            if seen.is_empty() {
                return None;
            }
            seen.sort_by(f64::total_cmp);
            let far = seen.iter().filter(|&&e| e > outlier).count();
            (2 * far > seen.len()).then(|| (name.clone(), seen[seen.len() / 2]))
        })
        .collect();
    outliers.sort_by(|a, b| b.1.total_cmp(&a.1));
    let split = 2 * outliers.len() >= runs[chosen].len();
    if split {
        outliers.clear();
    }
    Some(Consensus {
        chosen,
        scores,
        outliers,
        split,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Twelve cameras on a ring of radius 4 at height 2, named `r_<i>`.
    fn ring() -> Centres {
        (0..12)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 12.0;
                (
                    format!("r_{i}"),
                    DVec3::new(4.0 * a.cos(), 4.0 * a.sin(), 2.0),
                )
            })
            .collect()
    }

    /// `centres` in another gauge: rotated, scaled by 0.3 and shifted.
    fn regauged(centres: &Centres) -> Centres {
        let r = DMat3::from_euler(glam::EulerRot::XYZ, 0.4, -1.1, 2.0);
        centres
            .iter()
            .map(|(n, c)| (n.clone(), 0.3 * (r * *c) + DVec3::new(5.0, -2.0, 1.0)))
            .collect()
    }

    #[test]
    fn the_same_cameras_in_another_gauge_agree_exactly() {
        let d = disagreement(&ring(), &regauged(&ring())).unwrap();
        assert_eq!(d.len(), 12);
        assert!(d.iter().all(|e| e.1 < 1e-9), "{d:?}");
        let mut few = ring();
        few.retain(|n, _| n == "r_0" || n == "r_1");
        assert!(disagreement(&few, &ring()).is_none());
    }

    #[test]
    fn a_run_with_a_flipped_camera_is_not_chosen() {
        let good = ring();
        let mut other_good = regauged(&ring());
        for (k, c) in other_good.values_mut().enumerate() {
            *c += DVec3::splat(1e-3 * (k as f64).sin());
        }
        let mut flipped = ring();
        let r5 = flipped["r_5"];
        flipped.insert("r_5".into(), DVec3::new(-r5.x, -r5.y, r5.z));
        let runs = [flipped.clone(), good.clone(), other_good.clone()];
        let chosen = consensus(&runs, 0.9, 0.05).unwrap();
        assert_ne!(chosen.chosen, 0, "{chosen:?}");
        let [Some(bad), Some(a), Some(b)] = chosen.scores[..] else {
            panic!("{chosen:?}");
        };
        assert!(bad > 1.5 * a.max(b), "{chosen:?}");
        // The chosen run's r_5 agrees with one other run and not with the flipped one: kept.
        assert!(chosen.outliers.is_empty(), "{chosen:?}");
    }

    #[test]
    fn runs_that_registered_too_few_are_not_chosen() {
        let mut small = ring();
        small.retain(|n, _| n.len() == 3 && n < &"r_4".to_string());
        let runs = [small, ring()];
        let chosen = consensus(&runs, 0.9, 0.05).unwrap();
        assert_eq!(chosen.chosen, 1);
        assert_eq!(chosen.scores, vec![None, None]);
        assert!(consensus(&[Centres::new()], 0.9, 0.05).is_none());
    }

    #[test]
    fn a_camera_two_runs_place_apart_is_an_outlier_whichever_is_kept() {
        let mut shifted = ring();
        let c = shifted["r_3"];
        shifted.insert("r_3".into(), c + DVec3::new(0.0, 0.0, 1.5));
        let chosen = consensus(&[shifted, regauged(&ring())], 0.9, 0.05).unwrap();
        let names: Vec<&str> = chosen.outliers.iter().map(|o| o.0.as_str()).collect();
        assert_eq!(names, ["r_3"], "{chosen:?}");
        assert!(chosen.outliers[0].1 > 0.2, "{chosen:?}");
        assert!(!chosen.split);
    }

    #[test]
    fn two_runs_that_disagree_everywhere_name_no_outlier() {
        // One run bent: every camera's height grows with its angle, so no similarity maps
        // it onto the other and every shared camera lies far off.
        let mut bent = ring();
        for (k, c) in bent.values_mut().enumerate() {
            c.z += 0.8 * (k as f64 * 1.7).sin();
        }
        let runs = [bent, regauged(&ring())];
        let d = disagreement(&runs[0], &runs[1]).unwrap();
        let far = d.iter().filter(|e| e.1 > 0.05).count();
        assert!(
            2 * far >= d.len(),
            "the runs must disagree on most cameras: {d:?}"
        );
        let chosen = consensus(&runs, 0.9, 0.05).unwrap();
        assert!(chosen.split, "{chosen:?}");
        assert!(chosen.outliers.is_empty(), "{chosen:?}");
    }
}
