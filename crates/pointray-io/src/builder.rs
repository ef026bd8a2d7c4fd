//! Collects per-point values in file order and turns them into a recentred `PointCloud`.

use glam::{DVec3, Vec3};
use pointray::PointCloud;
use pointray::cloud::ScanAttributes;

/// Which optional attributes the file provides.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Attributes {
    pub normals: bool,
    pub radii: bool,
    pub colors: bool,
    pub scan: ScanFields,
}

/// Which scan attributes ([`ScanAttributes`]) the file provides.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ScanFields {
    pub intensity: bool,
    pub classification: bool,
    pub return_number: bool,
    pub gps_time: bool,
}

impl ScanFields {
    /// The names [`crate::FileInfo::vertex_properties`] lists for them.
    pub(crate) fn names(&self) -> impl Iterator<Item = String> {
        let fields = [
            (self.intensity, "intensity"),
            (self.classification, "classification"),
            (self.return_number, "return_number"),
            (self.gps_time, "gps_time"),
        ];
        fields.into_iter().filter(|(has, _)| *has).map(|(_, name)| name.to_string())
    }
}

/// The scan attributes' column names, as [`scan_column`] reduces them.
const SCAN_KEYS: [&str; 4] = ["intensity", "classification", "returnnumber", "gpstime"];

/// Which scan attribute a column of this name holds (0 intensity, 1 classification, 2 return
/// number, 3 GPS time): our names (`return_number`, `gps_time`), CloudCompare's scalar fields
/// (`scalar_Intensity`, `scalar_Return_Number`, `scalar_GpsTime`) and PDAL's (`Intensity`,
/// `Classification`, `ReturnNumber`, `GpsTime`): case, underscores and `scalar_` aside.
fn scan_column(name: &str) -> Option<usize> {
    let lower = name.to_ascii_lowercase();
    let key = lower.strip_prefix("scalar_").unwrap_or(&lower).replace('_', "");
    SCAN_KEYS.iter().position(|k| *k == key)
}

/// The index among `names` of the first column holding each scan attribute (in
/// [`scan_column`]'s order), where one does.
pub(crate) fn scan_columns<'a>(names: impl Iterator<Item = &'a str> + Clone) -> [Option<usize>; 4] {
    std::array::from_fn(|k| names.clone().position(|name| scan_column(name) == Some(k)))
}

impl ScanFields {
    /// The fields present in `columns` (each `Some` where a column holds it).
    pub(crate) fn of<T>(columns: &[Option<T>; 4]) -> Self {
        let [intensity, classification, return_number, gps_time] = std::array::from_fn(|k| columns[k].is_some());
        Self { intensity, classification, return_number, gps_time }
    }
}

impl PointRecord {
    /// Sets the scan attributes from their columns' values (`[intensity, class, return, time]`;
    /// a class or return outside `0..=255` saturates, NaN is 0).
    pub(crate) fn set_scan(&mut self, values: [Option<f64>; 4]) {
        let [intensity, class, ret, time] = values.map(|v| v.unwrap_or(0.0));
        (self.intensity, self.classification, self.return_number, self.gps_time) =
            (intensity as f32, class as u8, ret as u8, time);
    }
}

pub(crate) struct CloudBuilder {
    world: Vec<DVec3>,
    normals: Option<Vec<Vec3>>,
    radii: Option<Vec<f32>>,
    colors: Option<Vec<[f32; 3]>>,
    scan: ScanAttributes,
}

/// One point as read from a file; attributes the file lacks are ignored.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PointRecord {
    pub position: DVec3,
    pub normal: Vec3,
    pub radius: f32,
    pub color: [f32; 3],
    pub intensity: f32,
    pub classification: u8,
    pub return_number: u8,
    pub gps_time: f64,
    /// Which of the file's viewpoints saw it (an E57 file's scan).
    pub viewpoint: u16,
}

impl CloudBuilder {
    /// `capacity` must already be validated against the file size by the caller.
    pub(crate) fn new(capacity: usize, attributes: Attributes) -> Self {
        Self {
            world: Vec::with_capacity(capacity),
            normals: attributes.normals.then(|| Vec::with_capacity(capacity)),
            radii: attributes.radii.then(|| Vec::with_capacity(capacity)),
            colors: attributes.colors.then(|| Vec::with_capacity(capacity)),
            scan: ScanAttributes {
                intensity: attributes.scan.intensity.then(|| Vec::with_capacity(capacity)),
                classification: attributes.scan.classification.then(|| Vec::with_capacity(capacity)),
                return_number: attributes.scan.return_number.then(|| Vec::with_capacity(capacity)),
                gps_time: attributes.scan.gps_time.then(|| Vec::with_capacity(capacity)),
            },
        }
    }

    pub(crate) fn push(&mut self, point: &PointRecord) {
        self.world.push(point.position);
        if let Some(normals) = &mut self.normals {
            normals.push(point.normal);
        }
        if let Some(radii) = &mut self.radii {
            radii.push(point.radius);
        }
        if let Some(colors) = &mut self.colors {
            colors.push(point.color);
        }
        push_some(&mut self.scan.intensity, point.intensity);
        push_some(&mut self.scan.classification, point.classification);
        push_some(&mut self.scan.return_number, point.return_number);
        push_some(&mut self.scan.gps_time, point.gps_time);
    }

    pub(crate) fn has_colors(&self) -> bool {
        self.colors.is_some()
    }

    pub(crate) fn len(&self) -> usize {
        self.world.len()
    }

    /// Recentres on the bounding-box centre of the finite points. Non-finite coordinates are
    /// kept as they are (they become non-finite local positions) so the core decides what to
    /// do with them; they must not drag the origin to infinity.
    pub(crate) fn finish(self) -> PointCloud {
        let mut cloud = PointCloud::from_world_positions(&self.world);
        cloud.normals = self.normals;
        cloud.radii = self.radii;
        cloud.colors = self.colors;
        cloud.scan = self.scan;
        cloud
    }
}

/// Clouds read one by one, merged in order into one: each point's world position (as reading
/// the cloud alone holds it) placed by `place`, its normal
/// turned by `turn` (both told the cloud's number); normals, radii and colours kept where every
/// cloud has them, scan attributes where any has (zeros for the others); the merged cloud
/// recentred as a file's.
pub(crate) fn merge(
    clouds: Vec<PointCloud>,
    place: impl Fn(usize, DVec3) -> DVec3,
    turn: impl Fn(usize, Vec3) -> Vec3,
) -> PointCloud {
    let all = |has: fn(&PointCloud) -> bool| clouds.iter().all(has);
    let attributes = Attributes {
        normals: all(|c| c.normals.is_some()),
        radii: all(|c| c.radii.is_some()),
        colors: all(|c| c.colors.is_some()),
        ..Attributes::default()
    };
    let mut builder = CloudBuilder::new(clouds.iter().map(PointCloud::len).sum(), attributes);
    for (k, c) in clouds.iter().enumerate() {
        for i in 0..c.len() {
            builder.push(&PointRecord {
                position: place(k, c.world_position(i)),
                normal: c.normals.as_ref().map_or(Vec3::ZERO, |n| turn(k, n[i])),
                radius: c.radii.as_ref().map_or(0.0, |r| r[i]),
                color: c.colors.as_ref().map_or([0.0; 3], |col| col[i]),
                ..PointRecord::default()
            });
        }
    }
    let mut merged = builder.finish();
    let mut len = 0;
    for c in clouds {
        let n = c.len();
        merged.scan.append(len, c.scan, n);
        len += n;
    }
    merged
}

fn push_some<T>(values: &mut Option<Vec<T>>, value: T) {
    if let Some(values) = values {
        values.push(value);
    }
}

/// Colours read raw (text formats, PDAL's PCD channels): `0..=65535` if any channel exceeds
/// 255, else `0..=255` if any exceeds 1, else `0..=1`; scaled to `[0, 1]` and clamped (NaN
/// to 0).
pub(crate) fn scale_colors_to_unit(cloud: &mut PointCloud) {
    let Some(colors) = &mut cloud.colors else { return };
    let max = colors.iter().flatten().fold(0.0f32, |m, &c| m.max(c));
    let divisor = if max > 255.0 {
        65535.0
    } else if max > 1.0 {
        255.0
    } else {
        1.0
    };
    for color in colors.iter_mut() {
        *color = color.map(|c| if c.is_nan() { 0.0 } else { (c / divisor).clamp(0.0, 1.0) });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_points_do_not_move_the_origin() {
        let mut builder = CloudBuilder::new(4, Attributes::default());
        let points = [
            DVec3::new(1000.0, 0.0, 0.0),
            DVec3::new(f64::INFINITY, 0.0, 0.0),
            DVec3::new(1002.0, 2.0, 0.0),
            DVec3::new(5.0, 5.0, f64::NAN),
        ];
        for position in points {
            builder.push(&PointRecord { position, ..Default::default() });
        }
        let cloud = builder.finish();
        assert_eq!(cloud.origin, DVec3::new(1001.0, 1.0, 0.0));
        assert_eq!(cloud.len(), 4);
        assert!(cloud.positions[1].x.is_infinite());
        assert!(cloud.positions[3].z.is_nan());
    }
}
