//! Tiled surveys: several cloud files (an airborne survey's tiles, a scan campaign's exports)
//! read as one cloud. Each tile is read as it would be alone, then placed in the set's frame
//! as a scan set's scans are (`builder::merge`): its points' world positions as the tile's
//! cloud holds them (its origin plus their `f32` offsets, and their residuals where it keeps
//! them), recentred on the set's bounds. Reading the tiles in passes
//! (`prepare`) places them the same way, so both give the same cloud.

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use pointray::cloud::{WorldBounds, held, residual};

use crate::{FileInfo, IoError, LoadedCloud, ReadOptions, read_cloud_with};

/// Reads the tiles at `paths` (a lone path: that file) and merges them in order: normals, radii
/// and colours where every tile has them, the up axis and sun where every tile gives the same.
pub fn read_tiles(paths: &[PathBuf], options: &ReadOptions) -> Result<LoadedCloud, IoError> {
    if let [path] = paths {
        return read_cloud_with(path, options);
    }
    if paths.is_empty() {
        return Err(IoError::invalid(Path::new(""), "no input file"));
    }
    let loaded = paths.iter().map(|p| read_cloud_with(p, options)).collect::<Result<Vec<_>, _>>()?;
    let (clouds, infos): (Vec<_>, Vec<_>) = loaded.into_iter().map(|l| (l.cloud, l.info)).unzip();
    let info = FileInfo {
        format: format!("{} tiles, the first {}", paths.len(), infos[0].format),
        elements: paths.iter().zip(&clouds).map(|(p, c)| (p.display().to_string(), c.len())).collect(),
        vertex_properties: infos[0].vertex_properties.clone(),
        comments: Vec::new(),
        file_bytes: infos.iter().map(|i| i.file_bytes).sum(),
        up: agreed(infos.iter().map(|i| i.up)),
        sun: agreed(infos.iter().map(|i| i.sun)),
    };
    let cloud = crate::builder::merge(clouds, |_, world| world, |_, normal| normal);
    Ok(LoadedCloud { cloud, info })
}

/// What every tile gives alike, if they all do.
pub(crate) fn agreed<T: PartialEq>(mut values: impl Iterator<Item = Option<T>>) -> Option<T> {
    let first = values.next()??;
    values.all(|v| v.as_ref() == Some(&first)).then_some(first)
}

/// Where a point of a tile of bounds `tile` lies once that tile is read alone: as the tile's
/// cloud holds it ([`pointray::PointCloud::world_position`]: its offset rounded to `f32`, with what that
/// rounded off where the tile keeps it; see the module).
pub(crate) fn placed(position: DVec3, tile: &WorldBounds) -> DVec3 {
    let origin = tile.origin();
    let offset = (position - origin).as_vec3();
    let residual = if tile.keeps_residuals() { residual(position, origin, offset) } else { Vec3::ZERO };
    held(origin, offset, residual)
}

/// How errors about the set name it: its first file, and how many more.
pub fn set_name(paths: &[PathBuf]) -> PathBuf {
    match paths {
        [] => PathBuf::new(),
        [path] => path.clone(),
        [first, other] => PathBuf::from(format!("{} and {}", first.display(), other.display())),
        [first, rest @ ..] => PathBuf::from(format!("{} and {} other tiles", first.display(), rest.len())),
    }
}
