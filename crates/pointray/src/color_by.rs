//! Colour by attribute and class filters: how scan users look at lidar (Potree's and
//! CloudCompare's modes). Each point's colour is chosen here, before the splats are made, and
//! lit like any albedo; a level-of-detail representative averages its subtree's colours, which
//! is what many rays a pixel would average too. The attributes themselves stay with the cloud
//! (a ray query's splat id finds them).

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::PointCloud;
use crate::settings::SettingsError;

/// What a point's colour shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ColorBy {
    /// The file's colours; without them, the material's.
    #[default]
    Auto,
    /// The file's colours (refused without them).
    Rgb,
    /// The return's strength on the viridis ramp, from its 1st to its 99th percentile.
    Intensity,
    /// The ASPRS class colours (`classification_color`).
    Classification,
    /// Height along the up axis on the viridis ramp, 1st to 99th percentile.
    Elevation,
    /// The normal's components as red, green and blue (x, y, z from −1 to 1).
    Normal,
}

impl ColorBy {
    /// Its name as the settings write it.
    pub fn name(self) -> &'static str {
        match self {
            ColorBy::Auto => "auto",
            ColorBy::Rgb => "rgb",
            ColorBy::Intensity => "intensity",
            ColorBy::Classification => "classification",
            ColorBy::Elevation => "elevation",
            ColorBy::Normal => "normal",
        }
    }
}

/// Sets `cloud.colors` to what `by` shows (`up`: the elevation axis). Refused, naming the
/// option, where the cloud lacks the attribute.
pub fn apply(cloud: &mut PointCloud, by: ColorBy, up: Vec3) -> Result<(), SettingsError> {
    let missing = |what: &str| SettingsError::new("color_by", format!("{}: the cloud has no {what}", by.name()));
    let colors = match by {
        // A scanner's intensity is no albedo: the Stanford bunny's is a mottle over its fur.
        ColorBy::Auto => return Ok(()),
        ColorBy::Rgb => return if cloud.colors.is_some() { Ok(()) } else { Err(missing("colours")) },
        ColorBy::Intensity => {
            let intensity = cloud.scan.intensity.as_ref().ok_or_else(|| missing("intensity"))?;
            let scale = UnitScale::of(intensity);
            Some(intensity.iter().map(|&v| viridis(scale.unit(v))).collect())
        }
        ColorBy::Classification => {
            let classes = cloud.scan.classification.as_ref().ok_or_else(|| missing("classification"))?;
            Some(classes.iter().map(|&c| classification_color(c)).collect())
        }
        ColorBy::Elevation => {
            let heights: Vec<f32> = cloud.positions.iter().map(|&p| height(p, up)).collect();
            let scale = UnitScale::of(&heights);
            Some(heights.iter().map(|&h| viridis(scale.unit(h))).collect())
        }
        ColorBy::Normal => {
            let normals = cloud.normals.as_ref().ok_or_else(|| missing("normals"))?;
            Some(normals.iter().map(|&n| normal_color(n)).collect())
        }
    };
    cloud.colors = colors;
    Ok(())
}

/// Keeps the points whose class is in `keep` (all, if `None`) and not in `exclude`; returns the
/// kept points' former indices, or `None` when the filter keeps everything by definition.
/// Refused where a filter is asked of a cloud without classes, or nothing is left.
pub fn filter_classes(
    cloud: &mut PointCloud,
    keep: Option<&[u8]>,
    exclude: &[u8],
) -> Result<Option<Vec<u32>>, SettingsError> {
    if keep.is_none() && exclude.is_empty() {
        return Ok(None);
    }
    let option = if keep.is_some() { "classes" } else { "exclude_classes" };
    let Some(classes) = &cloud.scan.classification else {
        return Err(SettingsError::new(option, "needs classified points; the cloud has no classification"));
    };
    let kept: Vec<u32> = (0..classes.len() as u32).filter(|&i| drawn(classes[i as usize], keep, exclude)).collect();
    if kept.is_empty() {
        return Err(none_drawn(option, classes.iter().copied()));
    }
    cloud.permute(&kept);
    Ok(Some(kept))
}

/// Whether a point of class `c` is drawn: in `keep` (if given) and not in `exclude`.
pub fn drawn(c: u8, keep: Option<&[u8]>, exclude: &[u8]) -> bool {
    keep.is_none_or(|k| k.contains(&c)) && !exclude.contains(&c)
}

/// The refusal of a class filter (`option`) that drew none of the cloud's `classes`.
pub fn none_drawn(option: &'static str, classes: impl Iterator<Item = u8>) -> SettingsError {
    let mut present: Vec<u8> = classes.collect();
    present.sort_unstable();
    present.dedup();
    let present: Vec<String> = present.iter().map(u8::to_string).collect();
    SettingsError::new(option, format!("leaves no points (the cloud's classes: {})", present.join(", ")))
}

/// A point's height along `up` (normalised; +y if it is zero), which elevation colours show.
pub fn height(p: Vec3, up: Vec3) -> f32 {
    p.dot(up.normalize_or(Vec3::Y))
}

/// A normal's colour: its components as red, green and blue.
pub fn normal_color(n: Vec3) -> [f32; 3] {
    (n * 0.5 + 0.5).clamp(Vec3::ZERO, Vec3::ONE).to_array()
}

/// Values mapped to `[0, 1]` between the 1st and 99th percentiles of a cloud's (clamped), so
/// that a few outliers (a bird, a retro-reflector's intensity) do not squash the rest;
/// non-finite values to 0, and all to 0.5 where the finite ones span nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnitScale {
    lo: f32,
    hi: f32,
}

impl UnitScale {
    /// The scale of `values`.
    pub fn of(values: &[f32]) -> Self {
        let mut finite: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
        let ranks = percentile_ranks(finite.len());
        let mut at = |k: usize| *finite.select_nth_unstable_by(k, f32::total_cmp).1;
        ranks.map_or(Self { lo: 0.0, hi: 0.0 }, |[lo, hi]| Self { lo: at(lo), hi: at(hi) })
    }

    /// The scale whose percentiles are `lo` and `hi`: for values read in passes, whose finite
    /// values of [`percentile_ranks`] in `f32::total_cmp`'s order they are ((0, 0) without any).
    pub fn between(lo: f32, hi: f32) -> Self {
        Self { lo, hi }
    }

    pub fn unit(&self, v: f32) -> f32 {
        let span = self.hi - self.lo;
        match v.is_finite() {
            false => 0.0,
            true if span > 0.0 => ((v - self.lo) / span).clamp(0.0, 1.0),
            true => 0.5,
        }
    }
}

/// Where the 1st and 99th percentiles of `n` finite values lie in their order (none without).
pub fn percentile_ranks(n: usize) -> Option<[usize; 2]> {
    let last = n.checked_sub(1)?;
    Some([last / 100, last * 99 / 100])
}

/// The viridis ramp at `t` in `[0, 1]`, as sRGB-encoded channels in `[0, 1]`.
pub fn viridis(t: f32) -> [f32; 3] {
    srgb8(colorous::VIRIDIS.eval_continuous(f64::from(t)))
}

fn srgb8(c: colorous::Color) -> [f32; 3] {
    [c.r, c.g, c.b].map(|v| f32::from(v) / 255.0)
}

/// The colour of an ASPRS class code (LAS 1.4, table 17), in the conventions lidar viewers
/// share: ground brown, vegetation greens darkening with height, buildings orange-red, water
/// blue, noise magenta, wires yellow. Codes without a standard meaning (19–255, user-defined)
/// take a categorical palette's colours, so that distinct codes stay distinct.
pub fn classification_color(code: u8) -> [f32; 3] {
    let srgb: [u8; 3] = match code {
        0 => [190, 190, 190],  // created, never classified
        1 => [170, 170, 170],  // unclassified
        2 => [160, 110, 60],   // ground
        3 => [175, 220, 110],  // low vegetation
        4 => [95, 175, 65],    // medium vegetation
        5 => [35, 115, 45],    // high vegetation
        6 => [225, 90, 55],    // building
        7 => [255, 0, 255],    // low point (noise)
        8 => [255, 215, 0],    // model key-point (reserved in 1.4)
        9 => [40, 110, 230],   // water
        10 => [125, 75, 35],   // rail
        11 => [95, 95, 95],    // road surface
        12 => [240, 240, 110], // overlap (reserved in 1.4)
        13 => [255, 230, 150], // wire guard (shield)
        14 => [255, 200, 0],   // wire conductor (phase)
        15 => [200, 150, 50],  // transmission tower
        16 => [255, 160, 60],  // wire-structure connector
        17 => [150, 150, 205], // bridge deck
        18 => [255, 0, 150],   // high noise
        other => return srgb8(colorous::TABLEAU10[usize::from(other) % 10]),
    };
    srgb.map(|v| f32::from(v) / 255.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::ScanAttributes;

    fn cloud_of(classes: &[u8]) -> PointCloud {
        let positions = (0..classes.len()).map(|i| Vec3::new(0.0, i as f32, 0.0)).collect();
        let scan = ScanAttributes { classification: Some(classes.to_vec()), ..ScanAttributes::default() };
        PointCloud { scan, ..PointCloud::from_positions(positions) }
    }

    #[test]
    fn classes_take_their_asprs_colours() {
        let mut cloud = cloud_of(&[2, 6, 9, 200]);
        apply(&mut cloud, ColorBy::Classification, Vec3::Z).unwrap();
        let colors = cloud.colors.unwrap();
        assert_eq!(colors[0], classification_color(2));
        assert!(colors[0][0] > colors[0][2], "ground is brown");
        assert!(colors[1][0] > 0.8 && colors[1][2] < 0.3, "buildings are orange-red");
        assert!(colors[2][2] > 0.8 && colors[2][0] < 0.2, "water is blue");
        assert_ne!(colors[3], classification_color(201), "user codes stay distinct");
    }

    #[test]
    fn scalars_span_the_ramp_between_percentiles() {
        let mut cloud = cloud_of(&[0; 201]);
        // 0..=199 and one outlier far above: the percentiles are 2 and 198 (ranks 2 and 198
        // of 0..=200), so the outlier takes the ramp's end and does not squash the rest.
        let mut intensity: Vec<f32> = (0..200).map(|v| v as f32).collect();
        intensity.push(60_000.0);
        cloud.scan.intensity = Some(intensity);
        apply(&mut cloud, ColorBy::Intensity, Vec3::Y).unwrap();
        let colors = cloud.colors.unwrap();
        assert_eq!(colors[0], viridis(0.0));
        assert_eq!(colors[199], viridis(1.0));
        assert_eq!(colors[200], viridis(1.0));
        assert_eq!(colors[100], viridis(0.5));
        // Elevation runs along the up axis: +y here (positions go up in y).
        let mut cloud = cloud_of(&[0; 101]);
        apply(&mut cloud, ColorBy::Elevation, Vec3::Y).unwrap();
        let colors = cloud.colors.take().unwrap();
        assert_eq!((colors[0], colors[100]), (viridis(0.0), viridis(1.0)));
        apply(&mut cloud, ColorBy::Elevation, Vec3::Z).unwrap();
        assert!(cloud.colors.unwrap().iter().all(|c| *c == viridis(0.5)), "flat along z: the middle");
    }

    #[test]
    fn auto_shows_the_file_s_colours_or_none() {
        let mut cloud = cloud_of(&[1, 1, 1]);
        cloud.scan.intensity = Some(vec![10.0, 20.0, 30.0]);
        apply(&mut cloud, ColorBy::Auto, Vec3::Y).unwrap();
        assert!(cloud.colors.is_none(), "no colours: the material's");
        cloud.colors = Some(vec![[0.2, 0.4, 0.6]; 3]);
        apply(&mut cloud, ColorBy::Auto, Vec3::Y).unwrap();
        assert_eq!(cloud.colors.unwrap()[1], [0.2, 0.4, 0.6]);
    }

    #[test]
    fn a_missing_attribute_is_named() {
        let mut cloud = PointCloud::from_positions(vec![Vec3::ZERO]);
        for (by, what) in [
            (ColorBy::Rgb, "colours"),
            (ColorBy::Intensity, "intensity"),
            (ColorBy::Classification, "classification"),
            (ColorBy::Normal, "normals"),
        ] {
            let e = apply(&mut cloud, by, Vec3::Y).unwrap_err();
            assert_eq!(e.option, "color_by");
            assert!(e.problem.ends_with(&format!("the cloud has no {what}")), "{e}");
        }
        let e = filter_classes(&mut cloud, Some(&[2]), &[]).unwrap_err();
        assert_eq!(e.to_string(), "classes needs classified points; the cloud has no classification");
    }

    #[test]
    fn class_filters_keep_and_exclude() {
        let mut cloud = cloud_of(&[2, 6, 2, 7, 5]);
        assert_eq!(filter_classes(&mut cloud, None, &[]).unwrap(), None);
        assert_eq!(filter_classes(&mut cloud, Some(&[2, 7]), &[7]).unwrap(), Some(vec![0, 2]));
        assert_eq!(cloud.scan.classification, Some(vec![2, 2]));
        assert_eq!(cloud.positions, vec![Vec3::ZERO, Vec3::new(0.0, 2.0, 0.0)]);
        let mut cloud = cloud_of(&[2, 6, 2, 7, 5]);
        assert_eq!(filter_classes(&mut cloud, None, &[7, 5]).unwrap(), Some(vec![0, 1, 2]));
        let e = filter_classes(&mut cloud, Some(&[9]), &[]).unwrap_err();
        assert_eq!(e.to_string(), "classes leaves no points (the cloud's classes: 2, 6)");
    }
}
