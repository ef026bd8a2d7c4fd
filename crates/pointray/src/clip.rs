//! Clipping: a box and half-spaces that keep part of the points, for sections, plans and
//! cut-away views of a building or a statue. The points outside are left out before the
//! splats are made (a scene is built with its clip), so the accelerator, the camera's framing
//! and `crop_to_model` see only what is kept; a splat that straddles a plane is kept whole.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::PointCloud;
use crate::settings::SettingsError;

/// An axis-aligned box in the file's coordinates: the points inside it are kept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClipBox {
    pub min: DVec3,
    pub max: DVec3,
}

/// The half-space `normal · p ≤ offset`, in the file's coordinates: the points in it are kept
/// (the normal points to the side cut away).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClipPlane {
    pub normal: DVec3,
    pub offset: f64,
}

impl ClipBox {
    fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

impl ClipPlane {
    fn keeps(&self, p: DVec3) -> bool {
        self.normal.dot(p) <= self.offset
    }
}

/// Checks the box is a box and the planes have directions.
pub fn check(clip_box: Option<&ClipBox>, planes: &[ClipPlane]) -> Result<(), SettingsError> {
    if let Some(b) = clip_box {
        let ok = b.min.is_finite() && b.max.is_finite() && b.min.cmple(b.max).all();
        if !ok {
            return Err(SettingsError::new("clip_box", "must be finite with its minimum below its maximum"));
        }
    }
    for plane in planes {
        if !(plane.normal.is_finite() && plane.offset.is_finite() && plane.normal.length_squared() > 0.0) {
            return Err(SettingsError::new("clip_planes", "need a non-zero finite normal and a finite offset"));
        }
    }
    Ok(())
}

/// Keeps the points inside `clip_box` and on the kept side of every plane; returns the kept
/// points' former indices, or `None` where nothing clips. Refused where nothing is left.
pub fn clip(
    cloud: &mut PointCloud,
    clip_box: Option<&ClipBox>,
    planes: &[ClipPlane],
) -> Result<Option<Vec<u32>>, SettingsError> {
    if clip_box.is_none() && planes.is_empty() {
        return Ok(None);
    }
    let origin = cloud.origin;
    let kept_point = |i: u32| keeps(origin + cloud.positions[i as usize].as_dvec3(), clip_box, planes);
    let kept: Vec<u32> = (0..cloud.len() as u32).filter(|&i| kept_point(i)).collect();
    if kept.is_empty() {
        return Err(none_kept(planes));
    }
    cloud.permute(&kept);
    Ok(Some(kept))
}

/// Whether the point at world position `p` is inside the box (if any) and on every plane's kept
/// side.
pub fn keeps(p: DVec3, clip_box: Option<&ClipBox>, planes: &[ClipPlane]) -> bool {
    clip_box.is_none_or(|b| b.contains(p)) && planes.iter().all(|plane| plane.keeps(p))
}

/// The refusal of clips that keep no point.
pub fn none_kept(planes: &[ClipPlane]) -> SettingsError {
    let option = if planes.is_empty() { "clip_box" } else { "clip_planes" };
    SettingsError::new(option, "leaves no points")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_and_planes_keep_their_side() {
        let world: Vec<DVec3> = (0..10).map(|i| DVec3::new(1000.0 + f64::from(i), 0.0, 0.0)).collect();
        let mut cloud = PointCloud::from_world_positions(&world);
        let clip_box = ClipBox { min: DVec3::new(1002.0, -1.0, -1.0), max: DVec3::new(1007.5, 1.0, 1.0) };
        let plane = ClipPlane { normal: DVec3::X, offset: 1005.0 };
        assert_eq!(clip(&mut cloud, Some(&clip_box), &[plane]).unwrap(), Some(vec![2, 3, 4, 5]));
        assert_eq!(clip(&mut cloud, None, &[]).unwrap(), None);
        let away = ClipPlane { normal: -DVec3::X, offset: -2000.0 };
        assert_eq!(clip(&mut cloud, None, &[away]).unwrap_err().to_string(), "clip_planes leaves no points");
        assert_eq!(check(None, &[ClipPlane { normal: DVec3::ZERO, offset: 0.0 }]).unwrap_err().option, "clip_planes");
        let inverted = ClipBox { min: DVec3::ONE, max: DVec3::ZERO };
        assert_eq!(check(Some(&inverted), &[]).unwrap_err().option, "clip_box");
    }
}
