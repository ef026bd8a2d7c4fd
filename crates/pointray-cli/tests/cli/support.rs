//! Helpers for the end-to-end tests: running the binary, synthetic inputs, PNG decoding.

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Image size used by most render tests: small enough to keep every run well under a second.
pub const W: u32 = 48;
pub const H: u32 = 40;

/// The binary under test.
pub fn pointray() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_pointray"));
    // Keep backtraces out of stderr so "panicked" checks see the first line only, and make
    // sure no inherited setting changes the output.
    cmd.env_remove("RUST_LOG").env("RUST_BACKTRACE", "0").env("NO_COLOR", "1");
    cmd
}

/// What one run of the binary did.
pub struct Run {
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
    pub args: Vec<String>,
}

impl Run {
    pub fn ok(&self) -> bool {
        self.code == Some(0)
    }

    /// Panics (with the full output) unless the run exited 0 without panicking.
    #[track_caller]
    pub fn assert_success(&self) -> &Self {
        assert!(self.ok(), "expected success:\n{self}");
        self.assert_no_panic();
        self
    }

    /// Panics unless the run failed with `code`, without panicking.
    #[track_caller]
    pub fn assert_failure(&self, code: i32) -> &Self {
        assert_eq!(self.code, Some(code), "expected exit code {code}:\n{self}");
        self.assert_no_panic();
        self
    }

    #[track_caller]
    pub fn assert_no_panic(&self) {
        assert!(!self.stderr.contains("panicked"), "the binary panicked:\n{self}");
        assert!(!self.stdout.contains("panicked"), "the binary panicked:\n{self}");
    }

    #[track_caller]
    pub fn assert_stderr_contains(&self, needle: &str) -> &Self {
        assert!(self.stderr.contains(needle), "stderr lacks {needle:?}:\n{self}");
        self
    }

    #[track_caller]
    pub fn assert_stdout_contains(&self, needle: &str) -> &Self {
        assert!(self.stdout.contains(needle), "stdout lacks {needle:?}:\n{self}");
        self
    }
}

impl std::fmt::Display for Run {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let clip = |s: &str| {
            if s.len() > 4000 {
                let mut end = 4000;
                while !s.is_char_boundary(end) {
                    end -= 1;
                }
                format!("{}… ({} bytes)", &s[..end], s.len())
            } else {
                s.to_string()
            }
        };
        write!(
            f,
            "  args:   {:?}\n  code:   {:?}\n  stdout: {}\n  stderr: {}",
            self.args,
            self.code,
            clip(&self.stdout),
            clip(&self.stderr)
        )
    }
}

/// Runs `pointray args…` in `dir` and collects the output.
pub fn run_in(dir: &Path, args: &[&str]) -> Run {
    run_in_with_env(dir, args, &[])
}

/// [`run_in`] with the environment variables `env` set.
pub fn run_in_with_env(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Run {
    let mut command = pointray();
    command.envs(env.iter().copied());
    let output: Output = command.args(args).current_dir(dir).output().expect("spawn pointray");
    Run {
        code: output.status.code(),
        stdout: String::from_utf8_lossy(&output.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&output.stderr).into_owned(),
        args: args.iter().map(|s| s.to_string()).collect(),
    }
}

/// Runs `pointray -q render <args…> --width W --height H` in `dir` (size flags appended).
pub fn render_in(dir: &Path, args: &[&str]) -> Run {
    let (w, h) = (W.to_string(), H.to_string());
    let mut all = vec!["-q", "render"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--width", &w, "--height", &h]);
    run_in(dir, &all)
}

pub fn temp_dir() -> tempfile::TempDir {
    tempfile::Builder::new().prefix("pointray-cli-test").tempdir().expect("temp dir")
}

/// File names (not paths) in `dir`, hidden ones included.
pub fn dir_entries(dir: &Path) -> BTreeSet<String> {
    std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| e.expect("dir entry").file_name().to_string_lossy().into_owned())
        .collect()
}

#[track_caller]
pub fn assert_dir_contains_exactly(dir: &Path, expected: &[&str]) {
    let expected: BTreeSet<String> = expected.iter().map(|s| s.to_string()).collect();
    assert_eq!(dir_entries(dir), expected, "unexpected files in {}", dir.display());
}

/// A decoded 8-bit RGB image.
#[derive(Clone, PartialEq, Eq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl std::fmt::Debug for Image {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Image {}x{} ({} bytes)", self.width, self.height, self.rgb.len())
    }
}

impl Image {
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    pub fn pixels(&self) -> impl Iterator<Item = (u32, u32, [u8; 3])> + '_ {
        (0..self.height).flat_map(move |y| (0..self.width).map(move |x| (x, y, self.pixel(x, y))))
    }

    /// How many pixels differ from `colour`.
    pub fn count_not(&self, colour: [u8; 3]) -> usize {
        self.pixels().filter(|&(_, _, p)| p != colour).count()
    }
}

/// Decodes `path` as a PNG, insisting on 8-bit RGB (what the renderer writes).
#[track_caller]
pub fn read_png(path: &Path) -> Image {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "{} lacks the PNG signature", path.display());
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap_or_else(|e| panic!("{}: bad PNG header: {e}", path.display()));
    let size = reader.output_buffer_size().expect("sane PNG size");
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).unwrap_or_else(|e| panic!("{}: bad PNG data: {e}", path.display()));
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "{}", path.display());
    buf.truncate(info.width as usize * info.height as usize * 3);
    Image { width: info.width, height: info.height, rgb: buf }
}

/// The renderer's background (linear [0.010, 0.011, 0.019]) as the PNG stores it, sRGB 8-bit.
pub fn background_srgb8() -> [u8; 3] {
    [0.010f32, 0.011, 0.019].map(|c| {
        let s = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
        (s * 255.0 + 0.5) as u8
    })
}

/// Parses a `--stats` file.
#[track_caller]
pub fn read_stats(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{} is not JSON: {e}\n{text}", path.display()))
}

#[track_caller]
pub fn stat_f64(stats: &serde_json::Value, key: &str) -> f64 {
    stats
        .get(key)
        .and_then(serde_json::Value::as_f64)
        .unwrap_or_else(|| panic!("stats lack a number {key:?}: {stats:#}"))
}

#[track_caller]
pub fn stat_u64(stats: &serde_json::Value, key: &str) -> u64 {
    stats
        .get(key)
        .and_then(serde_json::Value::as_u64)
        .unwrap_or_else(|| panic!("stats lack an integer {key:?}: {stats:#}"))
}

/// `n` points spread evenly over the unit sphere (a Fibonacci lattice): deterministic, no
/// duplicates, a closed surface whose normals the pipeline can estimate and orient.
pub fn sphere_points(n: usize) -> Vec<[f32; 3]> {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let a = golden * i as f32;
            [r * a.cos(), r * a.sin(), z]
        })
        .collect()
}

/// ASCII PLY with `x y z` only (and `comments` comment lines in the header).
pub fn ascii_ply(points: &[[f32; 3]], comments: usize) -> String {
    let mut s = String::from("ply\nformat ascii 1.0\n");
    for i in 0..comments {
        writeln!(s, "comment synthetic test comment number {i}").unwrap();
    }
    writeln!(s, "element vertex {}", points.len()).unwrap();
    s.push_str("property float x\nproperty float y\nproperty float z\nend_header\n");
    for p in points {
        writeln!(s, "{} {} {}", p[0], p[1], p[2]).unwrap();
    }
    s
}

/// ASCII PLY with `x y z nx ny nz` (outward normals of a sphere centred at the origin).
pub fn ascii_ply_with_normals(points: &[[f32; 3]]) -> String {
    ascii_ply_normals(points, |p| {
        let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        [p[0] / l, p[1] / l, p[2] / l]
    })
}

/// ASCII PLY with `x y z nx ny nz`, every normal `normal`.
pub fn ascii_ply_facing(points: &[[f32; 3]], normal: [f32; 3]) -> String {
    ascii_ply_normals(points, |_| normal)
}

fn ascii_ply_normals(points: &[[f32; 3]], normal: impl Fn(&[f32; 3]) -> [f32; 3]) -> String {
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        points.len()
    );
    for p in points {
        let n = normal(p);
        writeln!(s, "{} {} {} {} {} {}", p[0], p[1], p[2], n[0], n[1], n[2]).unwrap();
    }
    s
}

/// Binary little-endian PLY, float `x y z`, declaring `declared` vertices but holding `points`.
pub fn binary_ply(points: &[[f32; 3]], declared: u64) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {declared}\n\
         property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    .into_bytes();
    for p in points {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// XYZ text: one `x y z` line per point.
pub fn xyz_text(points: &[[f32; 3]]) -> String {
    let mut s = String::new();
    for p in points {
        writeln!(s, "{} {} {}", p[0], p[1], p[2]).unwrap();
    }
    s
}

/// Writes `contents` to `dir/name` and returns the path.
pub fn write_file(dir: &Path, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap_or_else(|e| panic!("write {}: {e}", path.display()));
    path
}

/// The sphere test cloud (3000 points, positions only) as `dir/sphere.ply`.
pub fn write_sphere(dir: &Path) -> PathBuf {
    write_file(dir, "sphere.ply", ascii_ply(&sphere_points(3000), 0))
}

/// An ASCII PLY mesh of the unit octahedron: 6 vertices, 8 triangles.
pub fn octahedron_ply() -> String {
    let mut text = "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 8\nproperty list uchar int vertex_indices\nend_header\n"
        .to_string();
    text += "1 0 0\n-1 0 0\n0 1 0\n0 -1 0\n0 0 1\n0 0 -1\n";
    for [a, b, c] in [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]] {
        text += &format!("3 {a} {b} {c}\n");
    }
    text
}
