//! Scene files beside the command line: a scene file (`pointray_io::source` reads it) sets its
//! own camera, lights, materials and sky, and its render settings give way to the flags given.

use std::path::Path;

use pointray::settings::Settings;

use crate::args::{RenderArgs, Switch};
use crate::failure;

/// Flags that mean nothing beside a scene file, whose camera, lights, materials, sky and clouds'
/// files are its own: given, they are refused rather than silently ignored.
const SCENE_OWNS: [&str; 22] = [
    "eye",
    "look_at",
    "up",
    "fov",
    "lens_radius",
    "focus_distance",
    "view_dir",
    "view",
    "distance",
    "crop_to_model",
    "light_dir",
    "light_pos",
    "light_radius",
    "light_intensity",
    "material",
    "ior",
    "sky",
    "env_map",
    "env_rotation",
    "ground",
    "demo_points",
    "columns",
];

/// The settings of a render of the scene file at `path`: the scene's, but for the render
/// settings given as flags (`--spp 1 --width 320` for a quick look) and those a scene does not
/// set; a flag of [`SCENE_OWNS`] is an error.
pub fn settings(path: &Path, scene: &Settings, a: &RenderArgs) -> anyhow::Result<Settings> {
    if let Some(flag) = SCENE_OWNS.iter().find(|id| a.given(id)) {
        let flag = flag.replace('_', "-");
        let e = anyhow::anyhow!(
            "--{flag} does not apply to a scene file: {} sets its camera, lights, materials, sky and clouds",
            path.display()
        );
        return Err(failure::usage(e));
    }
    let mut settings = a.settings();
    let flags = settings.clone();
    // The camera is the scene's; the flags of SCENE_OWNS were refused above.
    (settings.eye, settings.look_at, settings.up) = (scene.eye, scene.look_at, scene.up);
    (settings.fov, settings.lens_radius, settings.focus_distance) =
        (scene.fov, scene.lens_radius, scene.focus_distance);
    macro_rules! unless_given {
        ($($flag:literal => $($field:ident),+;)*) => {
            $(if !a.given($flag) {
                $(settings.$field = scene.$field.clone();)+
            })*
        };
    }
    unless_given! {
        "width" => width;
        "height" => height;
        "spp" => spp;
        "max_depth" => max_depth;
        "seed" => seed;
        "surface" => surface;
        "integrator" => integrator;
        "ao_distance" => ao_distance;
        "sampler" => sampler;
        "filter" => filter;
        "tonemap" => tonemap;
        "exposure" => exposure;
        "no_shadows" => shadows;
        "color_by" => color_by;
        "edl" => edl;
        "prefilter" => prefilter;
    }
    // `lod_threshold = 0` is full detail, as `--lod off` is; `--lod` and `--lod-threshold`
    // each override their own half.
    settings.lod_threshold = match (a.given("lod"), a.given("lod_threshold")) {
        (false, false) => scene.lod_threshold,
        (true, false) if a.lod == Switch::On && scene.lod_threshold > 0.0 => scene.lod_threshold,
        _ => flags.lod_threshold,
    };
    settings
        .check()
        .map_err(|e| failure::usage(crate::commands::render::flag_error(e).context(path.display().to_string())))?;
    Ok(settings)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every flag of `render` is classified: refused beside a scene, set by the scene unless
    /// given, or applied as to any input. A new flag must be placed in one of the three.
    #[test]
    fn every_render_flag_is_refused_overridden_or_applied_beside_a_scene() {
        use clap::CommandFactory;
        // The `unless_given!` fields of `scene_args`, and the level of detail.
        let overridden = [
            "width",
            "height",
            "spp",
            "max_depth",
            "seed",
            "surface",
            "integrator",
            "ao_distance",
            "sampler",
            "filter",
            "tonemap",
            "exposure",
            "no_shadows",
            "color_by",
            "edl",
            "prefilter",
            "lod_threshold",
            "lod",
        ];
        let applied = [
            "inputs",
            "output",
            "threads",
            "accel",
            "projection",
            "sj_window",
            "sj_min_coverage",
            "sj_min_coverage_facing_away",
            "region",
            "shadow_offset",
            "diffuse_spread",
            "cull",
            "sphere_from_level",
            "classes",
            "exclude_classes",
            "clip_box",
            "clip_plane",
            "aov",
            "transparent",
            "bit_depth",
            "turntable",
            "frames",
            "fps",
            "stats",
            "bench_frames",
            "bench_builds",
            "k_normals",
            "k_radius",
            "radius_scale",
            "recompute",
            "strays",
            "outlier_std",
        ];
        let cli = crate::args::Cli::command();
        let render = cli.find_subcommand("render").expect("a render subcommand");
        let mut seen = 0;
        for arg in render.get_arguments().filter(|a| a.get_id() != "help") {
            let id = arg.get_id().as_str();
            let places = [SCENE_OWNS.contains(&id), overridden.contains(&id), applied.contains(&id)];
            assert_eq!(places.iter().filter(|&&p| p).count(), 1, "--{id} must be in exactly one list: {places:?}");
            seen += 1;
        }
        assert_eq!(seen, SCENE_OWNS.len() + overridden.len() + applied.len(), "a listed flag does not exist");
    }
}
