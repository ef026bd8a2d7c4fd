//! Integration tests of pointray-io: round trips, hand-written PLY in every encoding,
//! malformed input, XYZ, atomic writes and PNG. All data is synthetic, in temp dirs.

use std::path::{Path, PathBuf};

mod common;

use glam::{DVec3, Vec3};
use pointray::PointCloud;
use pointray::cloud::ScanAttributes;
use pointray_io::{
    Axes, FileInfo, IoError, atomic_write, read_cloud, read_png, write_ply, write_ply_with_axes, write_png,
};

// ---------------------------------------------------------------- hand-written PLY

#[derive(Clone, Copy)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn name(self) -> &'static str {
        match self {
            Ty::I8 => "char",
            Ty::U8 => "uchar",
            Ty::I16 => "short",
            Ty::U16 => "ushort",
            Ty::I32 => "int",
            Ty::U32 => "uint32",
            Ty::F32 => "float",
            Ty::F64 => "float64",
        }
    }

    fn encode(self, value: f64, big_endian: bool, out: &mut Vec<u8>) {
        macro_rules! put {
            ($t:ty) => {{
                let v = value as $t;
                out.extend_from_slice(&if big_endian { v.to_be_bytes() } else { v.to_le_bytes() });
            }};
        }
        match self {
            Ty::I8 => put!(i8),
            Ty::U8 => put!(u8),
            Ty::I16 => put!(i16),
            Ty::U16 => put!(u16),
            Ty::I32 => put!(i32),
            Ty::U32 => put!(u32),
            Ty::F32 => put!(f32),
            Ty::F64 => put!(f64),
        }
    }
}

enum Prop {
    Scalar(Ty, &'static str),
    List(Ty, Ty, &'static str),
}

enum Val {
    S(f64),
    L(Vec<f64>),
}

struct Elem {
    name: &'static str,
    props: Vec<Prop>,
    records: Vec<Vec<Val>>,
}

#[derive(Clone, Copy, PartialEq)]
enum Enc {
    Ascii,
    Le,
    Be,
}

fn encode_ply(encoding: Enc, elements: &[Elem]) -> Vec<u8> {
    let format = match encoding {
        Enc::Ascii => "ascii",
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    let mut out = format!("ply\nformat {format} 1.0\ncomment hand written\nobj_info test 1\n").into_bytes();
    for element in elements {
        out.extend(format!("element {} {}\n", element.name, element.records.len()).bytes());
        for prop in &element.props {
            let line = match prop {
                Prop::Scalar(ty, name) => format!("property {} {name}\n", ty.name()),
                Prop::List(count, item, name) => {
                    format!("property list {} {} {name}\n", count.name(), item.name())
                }
            };
            out.extend(line.bytes());
        }
    }
    out.extend(b"end_header\n");
    for element in elements {
        for record in &element.records {
            if encoding == Enc::Ascii {
                let mut words = Vec::new();
                for value in record {
                    match value {
                        Val::S(v) => words.push(v.to_string()),
                        Val::L(items) => {
                            words.push(items.len().to_string());
                            words.extend(items.iter().map(f64::to_string));
                        }
                    }
                }
                out.extend(words.join(" ").bytes());
                out.extend(b"\r\n");
                continue;
            }
            let big_endian = encoding == Enc::Be;
            for (prop, value) in element.props.iter().zip(record) {
                match (prop, value) {
                    (Prop::Scalar(ty, _), Val::S(v)) => ty.encode(*v, big_endian, &mut out),
                    (Prop::List(count, item, _), Val::L(items)) => {
                        count.encode(items.len() as f64, big_endian, &mut out);
                        for v in items {
                            item.encode(*v, big_endian, &mut out);
                        }
                    }
                    _ => panic!("record does not match its properties"),
                }
            }
        }
    }
    out
}

fn face_element(name: &'static str, count: Ty, index: Ty, faces: usize) -> Elem {
    Elem {
        name,
        props: vec![Prop::List(count, index, "vertex_indices"), Prop::Scalar(Ty::I16, "flags")],
        records: (0..faces).map(|i| vec![Val::L(vec![0.0, 1.0, (i % 3) as f64]), Val::S(-(i as f64))]).collect(),
    }
}

/// Three points with every kind of attribute in mixed types, wrapped in unrelated elements.
fn mixed_elements() -> Vec<Elem> {
    // (position, normal, radius, colour)
    type Point = ([f64; 3], [f64; 3], f64, [f64; 3]);
    let points: [Point; 3] = [
        ([1.5, -2.25, 7.0], [0.0, 0.0, 1.0], 0.125, [255.0, 0.0, 128.0]),
        ([1000.0, 0.5, -3.0], [0.6, 0.8, 0.0], 0.5, [0.0, 255.0, 1.0]),
        ([-0.75, 3.0, 0.0], [1.0, 0.0, 0.0], 2.0, [17.0, 34.0, 51.0]),
    ];
    let vertex = Elem {
        name: "vertex",
        props: vec![
            Prop::Scalar(Ty::F64, "x"),
            Prop::Scalar(Ty::I8, "confidence"),
            Prop::Scalar(Ty::F32, "y"),
            Prop::List(Ty::U16, Ty::U32, "tags"),
            Prop::Scalar(Ty::I32, "z"),
            Prop::Scalar(Ty::F32, "nx"),
            Prop::Scalar(Ty::F64, "ny"),
            Prop::Scalar(Ty::F32, "nz"),
            Prop::Scalar(Ty::U32, "intensity"),
            Prop::Scalar(Ty::F64, "radius"),
            Prop::Scalar(Ty::U8, "red"),
            Prop::Scalar(Ty::U8, "green"),
            Prop::Scalar(Ty::U8, "blue"),
            Prop::Scalar(Ty::U16, "alpha"),
        ],
        records: points
            .iter()
            .enumerate()
            .map(|(i, (p, n, r, c))| {
                vec![
                    Val::S(p[0]),
                    Val::S(-(i as f64)),
                    Val::S(p[1]),
                    Val::L((0..i).map(|t| t as f64 * 1000.0).collect()),
                    Val::S(p[2]),
                    Val::S(n[0]),
                    Val::S(n[1]),
                    Val::S(n[2]),
                    Val::S(4_000_000_000.0),
                    Val::S(*r),
                    Val::S(c[0]),
                    Val::S(c[1]),
                    Val::S(c[2]),
                    Val::S(65535.0),
                ]
            })
            .collect(),
    };
    let range_grid = Elem {
        name: "range_grid",
        props: vec![Prop::List(Ty::U8, Ty::I32, "vertex_indices")],
        records: vec![Val::L(vec![]), Val::L(vec![2.0]), Val::L(vec![])].into_iter().map(|v| vec![v]).collect(),
    };
    vec![
        face_element("face", Ty::U8, Ty::I32, 4),
        range_grid,
        vertex,
        face_element("face", Ty::I32, Ty::U32, 2),
        Elem { name: "empty_thing", props: vec![], records: vec![] },
    ]
}

// ---------------------------------------------------------------- helpers

fn temp_dir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

fn write_file(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write test file");
    path
}

fn world_positions(cloud: &PointCloud) -> Vec<DVec3> {
    cloud.positions.iter().map(|p| cloud.origin + p.as_dvec3()).collect()
}

fn assert_close(a: DVec3, b: DVec3, tolerance: f64) {
    assert!((a - b).abs().max_element() <= tolerance, "{a} vs {b}");
}

fn expect_error(path: &Path, fragment: &str) -> String {
    let message = match read_cloud(path) {
        Ok(loaded) => panic!("{} unexpectedly read {} points", path.display(), loaded.cloud.len()),
        Err(error) => error.to_string(),
    };
    let file_name = path.file_name().unwrap().to_string_lossy();
    assert!(message.contains(&*file_name), "{message:?} does not name {file_name}");
    assert!(message.contains(fragment), "{message:?} lacks {fragment:?}");
    message
}

fn sample_cloud(n: usize, offset: DVec3) -> (Vec<DVec3>, PointCloud) {
    let world: Vec<DVec3> = (0..n)
        .map(|i| {
            let t = i as f64;
            offset + DVec3::new((t * 0.37).sin() * 3.0, (t * 0.11).cos() * 2.0, t * 0.01)
        })
        .collect();
    (world.clone(), PointCloud::from_world_positions(&world))
}

// ---------------------------------------------------------------- round trips

#[test]
fn round_trip_positions_only() {
    let dir = temp_dir();
    let (world, cloud) = sample_cloud(100, DVec3::ZERO);
    let cloud = PointCloud { origin: DVec3::ZERO, positions: world.iter().map(|p| p.as_vec3()).collect(), ..cloud };
    let path = dir.path().join("plain.ply");
    write_ply(&path, &cloud).unwrap();
    let loaded = read_cloud(&path).unwrap();
    assert_eq!((loaded.info.format.as_str(), loaded.info.up), ("PLY binary_little_endian 1.0", None));
    assert_eq!(loaded.info.vertex_properties, vec!["float x", "float y", "float z"]);
    assert_eq!(loaded.info.file_bytes, std::fs::metadata(&path).unwrap().len());
    assert!(loaded.cloud.normals.is_none() && loaded.cloud.radii.is_none() && loaded.cloud.colors.is_none());
    for (read, truth) in world_positions(&loaded.cloud).iter().zip(&world) {
        assert_close(*read, *truth, 1e-5);
    }
}

#[test]
fn round_trip_with_all_attributes() {
    let dir = temp_dir();
    let (world, mut cloud) = sample_cloud(50, DVec3::new(1.0, 2.0, 3.0));
    let normals: Vec<Vec3> = (0..50).map(|i| Vec3::new(i as f32, 1.0, -2.0).normalize()).collect();
    let radii: Vec<f32> = (0..50).map(|i| 0.01 * (i + 1) as f32).collect();
    let colors: Vec<[f32; 3]> = (0..50).map(|i| [i as f32 / 49.0, 1.0 - i as f32 / 49.0, 0.5]).collect();
    cloud.normals = Some(normals.clone());
    cloud.radii = Some(radii.clone());
    cloud.colors = Some(colors.clone());
    let path = dir.path().join("full.ply");
    write_ply(&path, &cloud).unwrap();
    let loaded = read_cloud(&path).unwrap();
    // An origin nearer than the cloud is wide: floats keep what the offsets keep.
    assert!(loaded.info.vertex_properties.contains(&"float x".to_string()), "{:?}", loaded.info);
    let loaded = loaded.cloud;
    assert_eq!(loaded.len(), 50);
    for (read, truth) in world_positions(&loaded).iter().zip(&world) {
        assert_close(*read, *truth, 1e-5);
    }
    assert_eq!(loaded.normals.unwrap(), normals);
    assert_eq!(loaded.radii.unwrap(), radii);
    for (read, truth) in loaded.colors.unwrap().iter().zip(&colors) {
        for (a, b) in read.iter().zip(truth) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6, "{read:?} vs {truth:?}");
        }
    }
}

#[test]
fn round_trip_keeps_a_far_away_origin() {
    let dir = temp_dir();
    let far = DVec3::new(636_001.76, 5_112_345.25, 212.5);
    let (world, cloud) = sample_cloud(200, far);
    let path = dir.path().join("far.ply");
    write_ply(&path, &cloud).unwrap();
    let loaded = read_cloud(&path).unwrap();
    assert!(loaded.info.vertex_properties.contains(&"double x".to_string()));
    assert!((loaded.cloud.origin - far).length() < 10.0);
    for (read, truth) in world_positions(&loaded.cloud).iter().zip(&world) {
        assert_close(*read, *truth, 1e-3);
    }
}

#[test]
fn writing_an_inconsistent_cloud_is_refused() {
    let dir = temp_dir();
    let mut cloud = PointCloud::from_positions(vec![Vec3::ZERO; 3]);
    cloud.radii = Some(vec![1.0]);
    let path = dir.path().join("bad.ply");
    let message = write_ply(&path, &cloud).unwrap_err().to_string();
    assert!(message.contains("bad.ply") && message.contains("radii"), "{message}");
    assert!(!path.exists());
}

// ---------------------------------------------------------------- hand-written encodings

#[test]
fn all_three_encodings_read_to_the_same_cloud() {
    let dir = temp_dir();
    let elements = mixed_elements();
    let mut clouds = Vec::new();
    for (encoding, name) in [(Enc::Ascii, "mixed_ascii.ply"), (Enc::Le, "mixed_le.ply"), (Enc::Be, "mixed_be.ply")] {
        let path = write_file(dir.path(), name, &encode_ply(encoding, &elements));
        let loaded = read_cloud(&path).unwrap_or_else(|e| panic!("{e}"));
        check_info(&loaded.info);
        clouds.push(loaded.cloud);
    }
    let expected_world = [DVec3::new(1.5, -2.25, 7.0), DVec3::new(1000.0, 0.5, -3.0), DVec3::new(-0.75, 3.0, 0.0)];
    for cloud in &clouds {
        for (read, truth) in world_positions(cloud).iter().zip(&expected_world) {
            assert_close(*read, *truth, 1e-4);
        }
        let normals = cloud.normals.as_ref().unwrap();
        assert_eq!(normals[1], Vec3::new(0.6, 0.8, 0.0));
        assert_eq!(cloud.radii.as_ref().unwrap(), &vec![0.125, 0.5, 2.0]);
        let colors = cloud.colors.as_ref().unwrap();
        assert_eq!(colors[0], [1.0, 0.0, 128.0 / 255.0]);
        assert_eq!(colors[2], [17.0 / 255.0, 34.0 / 255.0, 51.0 / 255.0]);
    }
    for other in &clouds[1..] {
        assert_eq!(other.positions, clouds[0].positions);
        assert_eq!(other.origin, clouds[0].origin);
        assert_eq!(other.normals, clouds[0].normals);
        assert_eq!(other.radii, clouds[0].radii);
        assert_eq!(other.colors, clouds[0].colors);
    }
}

fn check_info(info: &FileInfo) {
    let names: Vec<(&str, usize)> = info.elements.iter().map(|(n, c)| (n.as_str(), *c)).collect();
    assert_eq!(names, vec![("face", 4), ("range_grid", 3), ("vertex", 3), ("face", 2), ("empty_thing", 0)]);
    assert_eq!(info.vertex_properties[0], "float64 x");
    assert_eq!(info.vertex_properties[3], "list ushort uint32 tags");
    assert_eq!(info.comments, vec!["hand written", "obj_info test 1"]);
}

#[test]
fn colours_as_ushort_and_float() {
    let dir = temp_dir();
    for (ty, values, expected) in [
        (Ty::U16, [65535.0, 0.0, 32767.0], [1.0, 0.0, 32767.0 / 65535.0]),
        (Ty::F32, [0.25, 1.5, -1.0], [0.25, 1.0, 0.0]),
        (Ty::F64, [0.5, 0.0, 1.0], [0.5, 0.0, 1.0]),
    ] {
        let vertex = Elem {
            name: "vertex",
            props: vec![
                Prop::Scalar(Ty::F32, "x"),
                Prop::Scalar(Ty::F32, "y"),
                Prop::Scalar(Ty::F32, "z"),
                Prop::Scalar(ty, "diffuse_red"),
                Prop::Scalar(ty, "diffuse_green"),
                Prop::Scalar(ty, "diffuse_blue"),
            ],
            records: vec![[0.0, 0.0, 0.0, values[0], values[1], values[2]].map(Val::S).into()],
        };
        for encoding in [Enc::Ascii, Enc::Le] {
            let path = write_file(
                dir.path(),
                &format!("colour_{}.ply", ty.name()),
                &encode_ply(encoding, &[vertex_clone(&vertex)]),
            );
            let colors = read_cloud(&path).unwrap().cloud.colors.unwrap();
            for (got, want) in colors[0].iter().zip(expected) {
                assert!((got - want as f32).abs() < 1e-6, "{}: {:?} vs {expected:?}", ty.name(), colors[0]);
            }
        }
    }
}

fn vertex_clone(element: &Elem) -> Elem {
    Elem {
        name: element.name,
        props: element
            .props
            .iter()
            .map(|p| match p {
                Prop::Scalar(t, n) => Prop::Scalar(*t, n),
                Prop::List(c, i, n) => Prop::List(*c, *i, n),
            })
            .collect(),
        records: element
            .records
            .iter()
            .map(|r| {
                r.iter()
                    .map(|v| match v {
                        Val::S(x) => Val::S(*x),
                        Val::L(xs) => Val::L(xs.clone()),
                    })
                    .collect()
            })
            .collect(),
    }
}

#[test]
fn normal_aliases_and_non_finite_coordinates() {
    let dir = temp_dir();
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                property float normal_x\nproperty float normal_y\nproperty float normal_z\nend_header\n\
                1 2 3 0 0 1\nnan 0 0 0 1 0\n3 4 inf 1 0 0\n";
    let path = write_file(dir.path(), "aliases.ply", text.as_bytes());
    let cloud = read_cloud(&path).unwrap().cloud;
    assert_eq!(cloud.len(), 3);
    assert_eq!(cloud.normals.as_ref().unwrap()[1], Vec3::Y);
    assert!(cloud.positions[1].x.is_nan());
    assert!(cloud.positions[2].z.is_infinite());
    assert!(cloud.origin.is_finite());
    assert_close(world_positions(&cloud)[0], DVec3::new(1.0, 2.0, 3.0), 1e-6);
}

// ---------------------------------------------------------------- malformed input

const SIMPLE_HEADER: &str = "ply\nformat binary_little_endian 1.0\nelement vertex 3\n\
                             property float x\nproperty float y\nproperty float z\nend_header\n";

fn simple_binary(count_in_header: &str, points: usize) -> Vec<u8> {
    let mut bytes = SIMPLE_HEADER.replace("vertex 3", &format!("vertex {count_in_header}")).into_bytes();
    for i in 0..points * 3 {
        bytes.extend((i as f32).to_le_bytes());
    }
    bytes
}

const SIMPLE_ASCII: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                            property float z\nend_header\n0 0 0\n1 1 1\n2 2 2\n";

#[test]
fn truncated_binary_body() {
    let dir = temp_dir();
    let mut bytes = simple_binary("3", 3);
    bytes.truncate(bytes.len() - 5);
    let path = write_file(dir.path(), "truncated.ply", &bytes);
    expect_error(&path, "file ends inside vertex 2 of 3");
    expect_error(&path, &format!("byte {}", bytes.len()));
}

#[test]
fn truncated_binary_list_element_before_vertex() {
    let dir = temp_dir();
    let mut bytes = encode_ply(Enc::Be, &mixed_elements());
    let header_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let full = bytes.clone();
    bytes.truncate(header_end + 10);
    let path = write_file(dir.path(), "short_faces.ply", &bytes);
    expect_error(&path, &format!("byte {header_end}: element 'face' declares 4 records of at least 3 bytes"));
    // Each face record is 15 bytes: the second one is cut.
    let path = write_file(dir.path(), "cut_faces.ply", &full[..header_end + 20]);
    expect_error(&path, "file ends inside face 1 of 4");
}

#[test]
fn truncated_ascii_line() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "short_line.ply", SIMPLE_ASCII.replace("1 1 1", "1 1").as_bytes());
    expect_error(&path, "line 9: vertex 1: expected 3 values, found 2");
    let path = write_file(dir.path(), "long_line.ply", SIMPLE_ASCII.replace("1 1 1", "1 1 1 1").as_bytes());
    expect_error(&path, "line 9: vertex 1: expected 3 values, found 4");
    let path = write_file(dir.path(), "few_lines.ply", SIMPLE_ASCII.replace("2 2 2\n", "").as_bytes());
    expect_error(&path, "file ends inside vertex 2 of 3");
}

#[test]
fn bad_token() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "bad_token.ply", SIMPLE_ASCII.replace("2 2 2", "2 zwei 2").as_bytes());
    expect_error(&path, "line 10: vertex 2: bad value 'zwei' for property 'y'");
}

#[test]
fn counts_larger_than_the_file() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "too_many.ply", &simple_binary("1000000", 3));
    expect_error(&path, "file ends inside vertex 3 of 1000000");
    let path = write_file(dir.path(), "absurd.ply", &simple_binary("18446744073709551615", 3));
    expect_error(&path, "file ends inside vertex 3 of 18446744073709551615");
    let text = SIMPLE_ASCII.replace("vertex 3", "vertex 99999999999");
    let path = write_file(dir.path(), "absurd_ascii.ply", text.as_bytes());
    expect_error(&path, "element 'vertex' declares 99999999999 records");
    let path = write_file(dir.path(), "overflow.ply", &simple_binary("99999999999999999999999", 3));
    expect_error(&path, "line 3: bad element count");
}

#[test]
fn header_problems() {
    let dir = temp_dir();
    let cases = [
        (
            "missing_x.ply",
            SIMPLE_ASCII.replace("property float x\n", "property float w\n"),
            "only part of 'x y z': 'x' missing",
        ),
        (
            "no_position.ply",
            SIMPLE_ASCII.replace("float x", "float a").replace("float y", "float b").replace("float z", "float c"),
            "no 'x y z'",
        ),
        ("unknown_type.ply", SIMPLE_ASCII.replace("float y", "float3 y"), "line 5: unknown property type 'float3'"),
        ("no_end.ply", SIMPLE_ASCII.split("end_header").next().unwrap().to_string(), "file ends before 'end_header'"),
        ("no_vertex.ply", SIMPLE_ASCII.replace("element vertex", "element point"), "no 'vertex' element"),
        ("version.ply", SIMPLE_ASCII.replace("1.0", "2.0"), "line 2: unsupported PLY version '2.0'"),
        ("encoding.ply", SIMPLE_ASCII.replace("ascii", "binary_middle_endian"), "unknown PLY encoding"),
        (
            "half_normal.ply",
            SIMPLE_ASCII.replace("property float z\n", "property float z\nproperty float nx\n"),
            "only part of 'nx ny nz'",
        ),
    ];
    for (name, text, fragment) in cases {
        let path = write_file(dir.path(), name, text.as_bytes());
        expect_error(&path, fragment);
    }
}

#[test]
fn empty_garbage_and_missing_files() {
    let dir = temp_dir();
    expect_error(&write_file(dir.path(), "empty.ply", b""), "file is empty");
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let garbage: Vec<u8> = (0..4096).map(|_| (xorshift(&mut state) >> 24) as u8).collect();
    expect_error(&write_file(dir.path(), "garbage.bin", &garbage), "unrecognised format");
    expect_error(&write_file(dir.path(), "garbage.ply", &garbage), "does not start with the line 'ply'");
    expect_error(&dir.path().join("missing.ply"), "No such file");
}

fn xorshift(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

/// Mutated and truncated copies of valid files must give `Ok` or `Err`, never a panic.
#[test]
fn mutations_never_panic() {
    let dir = temp_dir();
    let originals = [
        ("fuzz_le.ply", encode_ply(Enc::Le, &mixed_elements())),
        ("fuzz_be.ply", encode_ply(Enc::Be, &mixed_elements())),
        ("fuzz_ascii.ply", encode_ply(Enc::Ascii, &mixed_elements())),
        ("fuzz.las", las_bytes(&survey_points(60, |i| i as u16), false)),
        ("fuzz.laz", las_bytes(&survey_points(60, |i| i as u16), true)),
        ("fuzz.pcd", pcd_compressed(&pcd_points())),
    ];
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut outcomes = [0usize; 2];
    for round in 0..6000 {
        let (name, original) = &originals[round % originals.len()];
        let mut bytes = original.clone();
        let random = |state: &mut u64, below: usize| (xorshift(state) % below as u64) as usize;
        for _ in 0..1 + random(&mut state, 4) {
            let at = random(&mut state, bytes.len());
            match random(&mut state, 5) {
                0 => bytes[at] ^= 1 << random(&mut state, 8),
                1 => bytes[at] = b"0123456789 \n-.e"[random(&mut state, 15)],
                2 => bytes[at] = (xorshift(&mut state) >> 32) as u8,
                3 => bytes.truncate(at.max(1)),
                _ => bytes.insert(at, b'9'),
            }
        }
        let path = write_file(dir.path(), name, &bytes);
        let result: Result<_, IoError> = read_cloud(&path);
        if let Err(error) = &result {
            assert!(error.to_string().contains(name), "{error}");
        }
        outcomes[usize::from(result.is_ok())] += 1;
    }
    // Both outcomes must occur, or the mutations are too weak (or too strong) to test much.
    assert!(outcomes[0] > 100 && outcomes[1] > 100, "errors / successes: {outcomes:?}");
}

// ---------------------------------------------------------------- XYZ

#[test]
fn xyz_and_pts_columns() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "plain.xyz", b"# a scan\n\n1 2 3\n4.5 5 6 # trailing\n");
    let loaded = read_cloud(&path).unwrap();
    assert_eq!(loaded.info.format, "XYZ text");
    assert_eq!(loaded.info.elements, vec![("point".to_string(), 2)]);
    assert_eq!(loaded.info.comments, vec!["a scan"]);
    assert_close(world_positions(&loaded.cloud)[1], DVec3::new(4.5, 5.0, 6.0), 1e-6);

    let path = write_file(dir.path(), "normals.xyz", b"1,2,3,0,0,1\r\n4, 5, 6, 0, 1, 0\r\n");
    let cloud = read_cloud(&path).unwrap().cloud;
    assert_eq!(cloud.normals.unwrap(), vec![Vec3::Z, Vec3::Y]);
    assert!(cloud.colors.is_none());

    let path = write_file(dir.path(), "rgb.txt", b"1 2 3 255 0 51\n4 5 6 0 255 0\n");
    let cloud = read_cloud(&path).unwrap().cloud;
    assert_eq!(cloud.colors.unwrap(), vec![[1.0, 0.0, 0.2], [0.0, 1.0, 0.0]]);
    assert!(cloud.normals.is_none());

    let path = write_file(dir.path(), "full.pts", b"2\n1 2 3 0 0 1 0.5 0.25 1\n4 5 6 1 0 0 0 0 0\n");
    let cloud = read_cloud(&path).unwrap().cloud;
    assert_eq!(cloud.len(), 2);
    assert_eq!(cloud.normals.unwrap()[1], Vec3::X);
    assert_eq!(cloud.colors.unwrap()[0], [0.5, 0.25, 1.0]);

    // PTS as scanners write it: a count, then x y z intensity [r g b].
    let path = write_file(dir.path(), "scan.pts", b"2\n1 2 3 -1024 255 0 51\n4 5 6 300 0 255 0\n");
    let loaded = read_cloud(&path).unwrap();
    assert_eq!(loaded.info.vertex_properties, ["x", "y", "z", "intensity", "red", "green", "blue"]);
    assert_eq!(loaded.cloud.colors.as_deref(), Some(&[[1.0, 0.0, 0.2], [0.0, 1.0, 0.0]][..]));
    assert_close(world_positions(&loaded.cloud)[1], DVec3::new(4.0, 5.0, 6.0), 1e-6);
    // CloudCompare's `x y z R G B A`: the colour is the first three bytes.
    let path = write_file(dir.path(), "cc.txt", b"1 2 3 255 128 0 255\n4 5 6 0 0 255 255\n");
    let loaded = read_cloud(&path).unwrap();
    assert_eq!(loaded.info.vertex_properties, ["x", "y", "z", "red", "green", "blue", "alpha"]);
    assert_eq!(loaded.cloud.colors.as_deref(), Some(&[[1.0, 128.0 / 255.0, 0.0], [0.0, 0.0, 1.0]][..]));
    let path = write_file(dir.path(), "grey.pts", b"1 2 3 0.5\n4 5 6 0.25\n");
    let cloud = read_cloud(&path).unwrap().cloud;
    assert!(cloud.len() == 2 && cloud.colors.is_none() && cloud.normals.is_none());
}

#[test]
fn xyz_is_recognised_by_content_without_an_extension() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "scan_points", b"636001.76 5112345.25 212.5\n636002.76 5112346.25 213.5\n");
    let cloud = read_cloud(&path).unwrap().cloud;
    assert_close(world_positions(&cloud)[0], DVec3::new(636001.76, 5112345.25, 212.5), 1e-6);
}

#[test]
fn xyz_errors_name_the_line() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "bad.xyz", b"# header\n1 2 3\n4 5 x\n");
    expect_error(&path, "line 3: bad value 'x' in column 3");
    let path = write_file(dir.path(), "ragged.xyz", b"1 2 3\n\n4 5 6 7\n");
    expect_error(&path, "line 3: expected 3 values (x y z), found 4");
    let path = write_file(dir.path(), "five.xyz", b"1 2 3 4 5\n");
    expect_error(&path, "line 1: 5 values on the first line: no layout of 3, 4, 6, 7 or 9");
    // Named, the columns read; a PTS count line before them is still a count.
    let options = pointray_io::ReadOptions { columns: Some("x,y,z,_,c".parse().unwrap()) };
    let path = write_file(dir.path(), "five.pts", b"2\n1 2 3 4 5\n6 7 8 9 2\n");
    let cloud = pointray_io::read_cloud_with(&path, &options).unwrap().cloud;
    assert_eq!((cloud.len(), cloud.scan.classification), (2, Some(vec![5, 2])));
    let ply = write_file(dir.path(), "cloud.ply", &ascii_ply(&[(DVec3::ZERO, DVec3::Z)]));
    let e = pointray_io::read_cloud_with(&ply, &options).unwrap_err().to_string();
    assert!(e.ends_with("text columns were named, but this is a PLY, LAS/LAZ, PCD or E57 file"), "{e}");
}

// ---------------------------------------------------------------- atomic writes and PNG

fn directory_entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

#[test]
fn atomic_write_leaves_nothing_on_failure() {
    let dir = temp_dir();
    let path = dir.path().join("out.bin");
    let result = atomic_write(&path, |out| {
        out.write_all(b"partial")?;
        Err(std::io::Error::other("renderer gave up"))
    });
    let message = result.unwrap_err().to_string();
    assert!(message.contains("out.bin") && message.contains("renderer gave up"), "{message}");
    assert!(directory_entries(dir.path()).is_empty(), "{:?}", directory_entries(dir.path()));
}

#[test]
fn atomic_write_replaces_only_on_success() {
    let dir = temp_dir();
    let path = dir.path().join("out.bin");
    atomic_write(&path, |out| out.write_all(b"first")).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"first");
    let _ = atomic_write(&path, |out| {
        out.write_all(b"second, but broken")?;
        Err(std::io::Error::other("no"))
    });
    assert_eq!(std::fs::read(&path).unwrap(), b"first");
    atomic_write(&path, |out| out.write_all(b"third")).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"third");
    assert_eq!(directory_entries(dir.path()), vec!["out.bin"]);
}

#[test]
fn png_round_trip() {
    let dir = temp_dir();
    let (width, height) = (7u32, 5u32);
    let pixels: Vec<u8> = (0..width * height * 3).map(|i| (i * 37 % 256) as u8).collect();
    let path = dir.path().join("image.png");
    write_png(&path, width, height, &pixels).unwrap();
    let file = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut decoded = vec![0; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut decoded).unwrap();
    assert_eq!((frame.width, frame.height), (width, height));
    assert_eq!((frame.color_type, frame.bit_depth), (png::ColorType::Rgb, png::BitDepth::Eight));
    assert_eq!(&decoded[..frame.buffer_size()], &pixels[..]);

    let message = write_png(&dir.path().join("wrong.png"), 4, 4, &pixels).unwrap_err().to_string();
    assert!(message.contains("wrong.png") && message.contains("4x4"), "{message}");
}

#[test]
fn read_png_round_trips_write_png() {
    let dir = temp_dir();
    let (width, height) = (7u32, 5u32);
    let pixels: Vec<u8> = (0..width * height * 3).map(|i| (i * 53 % 256) as u8).collect();
    let path = dir.path().join("image.png");
    write_png(&path, width, height, &pixels).unwrap();
    assert_eq!(read_png(&path).unwrap(), (width, height, pixels));
}

/// Encodes a 2x1 image in any colour type and depth with the png crate itself.
fn encode_png(color: png::ColorType, depth: png::BitDepth, palette: Option<&[u8]>, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, 2, 1);
    encoder.set_color(color);
    encoder.set_depth(depth);
    if let Some(palette) = palette {
        encoder.set_palette(palette.to_vec());
    }
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(data).unwrap();
    writer.finish().unwrap();
    out
}

#[test]
fn read_png_converts_every_colour_type_to_rgb8() {
    use png::{BitDepth, ColorType};
    let dir = temp_dir();
    let rgb = [10, 20, 30, 200, 100, 0];
    let gray = [7, 7, 7, 250, 250, 250];
    let palette: [u8; 9] = [1, 2, 3, 10, 20, 30, 200, 100, 0];
    let cases = [
        ("gray.png", ColorType::Grayscale, BitDepth::Eight, None, vec![7, 250], gray),
        ("gray1.png", ColorType::Grayscale, BitDepth::One, None, vec![0b0100_0000], [0, 0, 0, 255, 255, 255]),
        ("gray_alpha.png", ColorType::GrayscaleAlpha, BitDepth::Eight, None, vec![7, 0, 250, 128], gray),
        ("rgb.png", ColorType::Rgb, BitDepth::Eight, None, rgb.to_vec(), rgb),
        ("rgba.png", ColorType::Rgba, BitDepth::Eight, None, vec![10, 20, 30, 0, 200, 100, 0, 255], rgb),
        // 16-bit samples keep their high byte.
        ("rgb16.png", ColorType::Rgb, BitDepth::Sixteen, None, rgb.iter().flat_map(|&c| [c, 0xff - c]).collect(), rgb),
        ("palette.png", ColorType::Indexed, BitDepth::Eight, Some(&palette), vec![1, 2], rgb),
    ];
    for (name, color, depth, palette, data, expected) in cases {
        let path = write_file(dir.path(), name, &encode_png(color, depth, palette.map(|p| p.as_slice()), &data));
        assert_eq!(read_png(&path).unwrap(), (2, 1, expected.to_vec()), "{name}");
    }
}

#[test]
fn read_png_errors_name_the_file() {
    let dir = temp_dir();
    let path = dir.path().join("whole.png");
    write_png(&path, 16, 16, &[99; 16 * 16 * 3]).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let cases = [
        ("truncated.png", &bytes[..bytes.len() / 2], "ends early"),
        ("header_only.png", &bytes[..20], "ends early"),
        ("not_a.png", b"P6 1 1 255\n\0\0\0".as_slice(), "not a readable PNG"),
    ];
    for (name, contents, fragment) in cases {
        let path = write_file(dir.path(), name, contents);
        let message = read_png(&path).unwrap_err().to_string();
        assert!(message.contains(name) && message.contains(fragment), "{message}");
    }
    let message = read_png(&dir.path().join("missing.png")).unwrap_err().to_string();
    assert!(message.contains("missing.png"), "{message}");
}

#[test]
fn read_png_refuses_a_header_larger_than_the_file() {
    let dir = temp_dir();
    let path = dir.path().join("big.png");
    write_png(&path, 1, 1, &[0, 0, 0]).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    // IHDR data starts at byte 16 (signature 8, length 4, type 4): claim 60000 x 60000 and
    // fix the chunk's CRC so only the size check can object.
    bytes[16..24].copy_from_slice(&[0, 0, 0xea, 0x60, 0, 0, 0xea, 0x60]);
    let crc = crc32(&bytes[12..29]);
    bytes[29..33].copy_from_slice(&crc.to_be_bytes());
    let path = write_file(dir.path(), "big.png", &bytes);
    let message = read_png(&path).unwrap_err().to_string();
    assert!(message.contains("big.png") && message.contains("60000x60000"), "{message}");
}

/// The PNG chunk checksum (CRC-32, ISO 3309), bit by bit: only a few bytes are checked here.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

// ---------------------------------------------------------------- Stanford scan sets

/// An ascii PLY of positions and normals.
fn ascii_ply(points: &[(DVec3, DVec3)]) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        points.len()
    );
    for (p, n) in points {
        out += &format!("{} {} {} {} {} {}\n", p.x, p.y, p.z, n.x, n.y, n.z);
    }
    out.into_bytes()
}

#[test]
fn a_scan_set_merges_its_scans_registered() {
    use glam::DQuat;
    let dir = temp_dir();
    // Two scans of one curve in world space, each stored in its own frame: world = R⁻¹·local + t,
    // so local = R·(world − t).
    let world: Vec<(DVec3, DVec3)> = (0..200)
        .map(|i| {
            let a = i as f64 * 0.05;
            (DVec3::new(a.cos(), a.sin(), 0.1 * a), DVec3::new(a.cos(), a.sin(), 0.0))
        })
        .collect();
    let frames = [
        (DQuat::IDENTITY, DVec3::ZERO),
        (DQuat::from_axis_angle(DVec3::new(0.2, 1.0, 0.3).normalize(), 0.7), DVec3::new(0.05, -0.02, 0.01)),
    ];
    let mut conf = String::from("camera 0 0 -1 0 0 0 1\n# a comment\n");
    for (k, (q, t)) in frames.iter().enumerate() {
        let local: Vec<(DVec3, DVec3)> =
            world[k * 100..(k + 1) * 100].iter().map(|(p, n)| (*q * (*p - *t), *q * *n)).collect();
        write_file(dir.path(), &format!("scan{k}.ply"), &ascii_ply(&local));
        conf += &format!("bmesh scan{k}.ply {} {} {} {} {} {} {}\n", t.x, t.y, t.z, q.x, q.y, q.z, q.w);
    }
    let path = write_file(dir.path(), "set.conf", conf.as_bytes());
    let loaded = read_cloud(&path).expect("the scan set reads");
    assert_eq!(loaded.info.elements, vec![("scan0.ply".to_string(), 100), ("scan1.ply".to_string(), 100)]);
    let normals = loaded.cloud.normals.as_ref().expect("every scan has normals");
    for (i, p) in world_positions(&loaded.cloud).iter().enumerate() {
        assert_close(*p, world[i].0, 1e-5);
        assert_close(normals[i].as_dvec3(), world[i].1, 1e-5);
    }
}

#[test]
fn a_scan_set_keeps_its_scans_attributes() {
    let dir = temp_dir();
    let scan = |intensity: [u8; 2]| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
             property uchar intensity\nend_header\n0 0 0 {}\n1 0 0 {}\n",
            intensity[0], intensity[1]
        )
    };
    write_file(dir.path(), "a.ply", scan([1, 2]).as_bytes());
    write_file(dir.path(), "b.ply", scan([3, 4]).as_bytes());
    let conf = "bmesh a.ply 0 0 0 0 0 0 1\nbmesh b.ply 0 0 1 0 0 0 1\n";
    let cloud = read_cloud(&write_file(dir.path(), "set.conf", conf.as_bytes())).unwrap().cloud;
    assert_eq!(cloud.scan.intensity, Some(vec![1.0, 2.0, 3.0, 4.0]));
}

#[test]
fn scan_set_errors_name_the_file_and_line() {
    let dir = temp_dir();
    write_file(dir.path(), "ok.ply", &ascii_ply(&[(DVec3::ZERO, DVec3::Z), (DVec3::X, DVec3::Z)]));
    let cases = [
        (
            "word.conf",
            "bmesh ok.ply 0 0 0 0 0 0 1\nmesh ok.ply 0 0 0 0 0 0 1\n",
            "line 2: expected 'camera' or 'bmesh'",
        ),
        ("short.conf", "bmesh ok.ply 0 0 0 0 0 1\n", "line 1: bmesh ok.ply: expected 7 finite numbers"),
        ("nan.conf", "bmesh ok.ply 0 0 nan 0 0 0 1\n", "line 1: bmesh ok.ply: expected 7 finite numbers"),
        ("zero.conf", "bmesh ok.ply 0 0 0 0 0 0 0\n", "far from unit length"),
        ("missing.conf", "camera 0 0 0 0 0 0 1\nbmesh gone.ply 0 0 0 0 0 0 1\n", "line 2: bmesh gone.ply"),
        ("none.conf", "camera 0 0 0 0 0 0 1\n", "lists no 'bmesh' scan"),
        ("nested.conf", "bmesh word.conf 0 0 0 0 0 0 1\n", "cannot list another scan set"),
        // A device would be read without end; a scan must be a regular file.
        ("device.conf", "bmesh /dev/zero 0 0 0 0 0 0 1\n", "line 1: bmesh /dev/zero: /dev/zero: not a regular file"),
    ];
    for (name, text, _) in cases {
        write_file(dir.path(), name, text.as_bytes());
    }
    for (name, _, fragment) in cases {
        expect_error(&dir.path().join(name), fragment);
    }
}

// ---------------------------------------------------------------- LAS and LAZ

/// A LAS (or, `compressed`, LAZ) file of `points` (survey coordinates, 16-bit colour channels),
/// at 0.01 units, offset near the points as survey files are.
fn las_bytes(points: &[(DVec3, [u16; 3])], compressed: bool) -> Vec<u8> {
    las_bytes_of_version(points, compressed, (1, 2))
}

fn las_bytes_of_version(points: &[(DVec3, [u16; 3])], compressed: bool, version: (u8, u8)) -> Vec<u8> {
    las_bytes_with(points, compressed, version, |_, point| point)
}

/// [`las_bytes_of_version`], each point `edit`ed (given its index) before it is written.
fn las_bytes_with(
    points: &[(DVec3, [u16; 3])],
    compressed: bool,
    version: (u8, u8),
    edit: impl Fn(usize, las::Point) -> las::Point,
) -> Vec<u8> {
    let mut builder = las::Builder::from(version);
    builder.point_format = las::point::Format::new(3).unwrap();
    builder.point_format.is_compressed = compressed;
    let t = |offset| las::Transform { scale: 0.01, offset };
    builder.transforms = las::Vector { x: t(636_000.0), y: t(849_000.0), z: t(400.0) };
    let header = builder.into_header().unwrap();
    let mut writer = las::Writer::new(std::io::Cursor::new(Vec::new()), header).unwrap();
    for (i, (p, [red, green, blue])) in points.iter().enumerate() {
        let point = las::Point {
            x: p.x,
            y: p.y,
            z: p.z,
            color: Some(las::Color { red: *red, green: *green, blue: *blue }),
            gps_time: Some(0.0),
            ..Default::default()
        };
        writer.write_point(edit(i, point)).unwrap();
    }
    writer.into_inner().unwrap().into_inner()
}

fn survey_points(n: usize, channel: impl Fn(usize) -> u16) -> Vec<(DVec3, [u16; 3])> {
    (0..n)
        .map(|i| {
            let a = i as f64;
            let p =
                DVec3::new(636_001.0 + (a * 0.37).sin() * 500.0, 849_100.0 + a * 0.25, 410.0 + (a * 0.1).cos() * 50.0);
            // On the file's 0.01 grid, so that reading back is exact up to f64 rounding.
            ((p * 100.0).round() / 100.0, [channel(i), channel(i + 1), channel(i + 2)])
        })
        .collect()
}

#[test]
fn las_and_laz_read_to_the_same_survey_cloud_with_its_colours() {
    let dir = temp_dir();
    let points = survey_points(3_000, |i| (i % 200) as u16 + 40);
    let las = write_file(dir.path(), "a.las", &las_bytes(&points, false));
    let laz = write_file(dir.path(), "b.laz", &las_bytes(&points, true));
    let (a, b) = (read_cloud(&las).unwrap(), read_cloud(&laz).unwrap());
    assert_eq!(a.info.format, "LAS 1.2, point format 3");
    assert_eq!(b.info.format, "LAZ 1.2, point format 3");
    // A LAS 1.1 file is named 1.1 (the reader calls it 1.2: point format 3 is 1.2's).
    let mut old = las_bytes(&points[..10], false);
    old[25] = 1;
    assert_eq!(read_cloud(&write_file(dir.path(), "c.las", &old)).unwrap().info.format, "LAS 1.1, point format 3");
    // Surveys stand on z: the camera's default up for them.
    assert_eq!((a.info.up, b.info.up), (Some([0.0, 0.0, 1.0]), Some([0.0, 0.0, 1.0])));
    // And are lit by a sun from the north-west at 45°.
    assert_eq!((a.info.sun, b.info.sun), (Some(pointray_io::SURVEY_SUN), Some(pointray_io::SURVEY_SUN)));
    assert!(std::fs::metadata(&laz).unwrap().len() < std::fs::metadata(&las).unwrap().len() / 2, "LAZ compresses");
    // Large offsets survive: recentred in f64, positions keep f32 precision over the cloud's
    // ~1,000-unit extent (6·10⁻⁵), where f32 at 636,000 would round to 0.06.
    for loaded in [&a, &b] {
        let world = world_positions(&loaded.cloud);
        for (w, (p, _)) in world.iter().zip(&points) {
            assert_close(*w, *p, 1e-4);
        }
    }
    assert_eq!(a.cloud.positions, b.cloud.positions);
    // 8-bit values in 16-bit fields (all ≤ 255): read as 8-bit.
    let colors = a.cloud.colors.as_ref().expect("point format 3 has colour");
    assert_eq!(colors[0], [40.0 / 255.0, 41.0 / 255.0, 42.0 / 255.0]);
    assert_eq!(a.cloud.colors, b.cloud.colors);
}

/// A survey in tiles (a LAS and a LAZ file, side by side in survey coordinates) reads as one
/// cloud, and prepares to the same scene file in memory and out of core, each tile's points
/// placed as reading it alone places them.
#[test]
fn a_survey_in_tiles_is_one_cloud_and_one_scene_file_either_way() {
    let dir = temp_dir();
    // The east tile 1 km wide, the west one 10 m: the set's centre falls inside the east tile,
    // 500 m from its own, where the tile's f32 offsets are coarser than the set's.
    let mut points = survey_points(4_000, |i| (i % 200) as u16 + 40);
    for (p, _) in &mut points[..1_000] {
        p.x = ((634_500.0 + (p.x - 635_501.0) / 100.0) * 100.0).round() / 100.0;
    }
    let (west, east) = points.split_at(1_000);
    let tiles = [
        write_file(dir.path(), "west.las", &las_bytes(west, false)),
        write_file(dir.path(), "east.laz", &las_bytes(east, true)),
    ];
    let loaded = pointray_io::read_tiles(&tiles, &Default::default()).unwrap();
    assert_eq!(loaded.cloud.len(), 4_000);
    assert_eq!((loaded.info.up, loaded.info.sun), (Some([0.0, 0.0, 1.0]), Some(pointray_io::SURVEY_SUN)));
    assert!(loaded.cloud.colors.is_some() && loaded.cloud.scan.gps_time.is_some());
    for (w, (p, _)) in world_positions(&loaded.cloud).iter().zip(&points) {
        assert_close(*w, *p, 1e-4);
    }
    let config = pointray::preprocess::PreprocessConfig::standard();
    let source = pointray_io::source::load_tiles(&tiles, &config, &Default::default(), &|_| {}).unwrap();
    let scene = pointray::Scene::build(source.parts, &pointray::Settings::default()).unwrap();
    let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
    pointray_io::prs::write_prs(&memory, &scene).unwrap();
    let options = pointray_io::prepare::OutOfCore { preprocess: config, ..Default::default() };
    pointray_io::prepare::prepare_out_of_core(&tiles, &streamed, &options, &|_| {}).unwrap();
    assert!(std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(), "the files differ");
    // A tile that is not there is named.
    let missing = [tiles[0].clone(), dir.path().join("north.las")];
    let e = pointray_io::prepare::prepare_out_of_core(&missing, &streamed, &options, &|_| {}).unwrap_err();
    assert!(e.to_string().contains("north.las"), "{e}");
}

/// Out of core, the build's settings do to a survey what they do in memory: classes drawn or
/// left out, clips, colours by intensity, class, elevation or normal, bounding spheres: the same
/// scene file, byte for byte; and the same refusals.
#[test]
fn build_settings_out_of_core_make_the_scene_file_made_in_memory() {
    use pointray::clip::{ClipBox, ClipPlane};
    use pointray::color_by::ColorBy;
    let dir = temp_dir();
    let points = survey_points(3_000, |i| (i % 200) as u16 + 40);
    let classes = [1u8, 2, 3, 5, 6];
    let bytes = las_bytes_with(&points, true, (1, 2), |i, point| las::Point {
        classification: las::point::Classification::new(classes[i % 5]).unwrap(),
        intensity: (i * 37 % 1000) as u16,
        ..point
    });
    let survey = [write_file(dir.path(), "survey.laz", &bytes)];
    let config = pointray::preprocess::PreprocessConfig::standard();
    let both_ways = |settings: &pointray::Settings| {
        let source = pointray_io::source::load_tiles(&survey, &config, &Default::default(), &|_| {}).unwrap();
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        let scene = pointray::Scene::build(source.parts, settings).map(|s| pointray_io::prs::write_prs(&memory, &s));
        let options =
            pointray_io::prepare::OutOfCore { preprocess: config, settings: settings.clone(), ..Default::default() };
        let out_of_core = pointray_io::prepare::prepare_out_of_core(&survey, &streamed, &options, &|_| {});
        match (scene, out_of_core) {
            (Ok(written), Ok(_)) => {
                written.unwrap();
                assert!(
                    std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(),
                    "{settings:?}: the files differ"
                );
                None
            }
            (Err(pointray::scene::SceneError::Settings(a)), Err(pointray_io::prepare::SceneFileError::Unmet(b))) => {
                assert_eq!((a.option, &a.problem), (b.option, &b.problem));
                Some(a.problem)
            }
            (a, b) => panic!("{settings:?}: in memory {:?}, out of core {:?}", a.err(), b.err()),
        }
    };
    let (lo, hi) = (DVec3::new(635_800.0, 849_100.0, 380.0), DVec3::new(636_300.0, 849_600.0, 470.0));
    let plane = ClipPlane { normal: DVec3::new(0.0, 1.0, 0.0), offset: 849_500.0 };
    let cases = [
        pointray::Settings { color_by: ColorBy::Intensity, ..Default::default() },
        pointray::Settings { color_by: ColorBy::Classification, classes: Some(vec![2, 3, 6]), ..Default::default() },
        pointray::Settings {
            color_by: ColorBy::Elevation,
            exclude_classes: vec![1],
            clip_box: Some(ClipBox { min: lo, max: hi }),
            ..Default::default()
        },
        pointray::Settings {
            color_by: ColorBy::Normal,
            clip_planes: vec![plane],
            sphere_from_level: pointray::accel::bvh::NodeBounds::SpheresFrom(1),
            surface: pointray::splat::scheme::SurfaceKind::Rfd,
            ..Default::default()
        },
    ];
    for settings in &cases {
        assert_eq!(both_ways(settings), None);
    }
    let none = pointray::Settings { classes: Some(vec![9]), ..Default::default() };
    assert_eq!(both_ways(&none).unwrap(), "leaves no points (the cloud's classes: 1, 2, 3, 5, 6)");
    let far = ClipBox { min: DVec3::splat(0.0), max: DVec3::splat(1.0) };
    assert_eq!(
        both_ways(&pointray::Settings { clip_box: Some(far), ..Default::default() }).unwrap(),
        "leaves no points"
    );
}

/// A cloud of more parts than one (parts of at most 3,000 splats here, of 2²⁶ by default)
/// prepared out of core is the two-level scene built in memory, byte for byte, each part in its
/// frame: plain, and filtered and coloured with outliers dropped.
#[test]
fn a_scene_in_parts_prepared_out_of_core_is_the_one_built_in_memory() {
    use pointray::color_by::ColorBy;
    let dir = temp_dir();
    let origin = DVec3::new(500_000.0, 4_000_000.0, 100.0);
    let cloud = PointCloud { origin, ..common::classified_sphere(12_000) };
    let input = [dir.path().join("sphere.ply")];
    pointray_io::write_ply(&input[0], &cloud).unwrap();
    let limits = pointray::scene::BuildLimits { chunk_splats: 700, part_splats: 3_000 };
    let cases = [
        (pointray::Settings::default(), None),
        (
            pointray::Settings { color_by: ColorBy::Intensity, exclude_classes: vec![5], ..Default::default() },
            Some(1.0),
        ),
    ];
    for (settings, outlier_std) in cases {
        let config = pointray::preprocess::PreprocessConfig { outlier_std, ..Default::default() };
        let source = pointray_io::source::load_tiles(&input, &config, &Default::default(), &|_| {}).unwrap();
        let scene = pointray::Scene::build_with_limits(source.parts, &settings, limits).unwrap();
        assert!(scene.parts() >= 4, "{} parts", scene.parts());
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        pointray_io::prs::write_prs(&memory, &scene).unwrap();
        let options = pointray_io::prepare::OutOfCore { preprocess: config, settings, limits, ..Default::default() };
        let done = pointray_io::prepare::prepare_out_of_core(&input, &streamed, &options, &|_| {}).unwrap();
        assert_eq!(done.parts, scene.parts());
        assert!(
            std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(),
            "{outlier_std:?}: the files differ"
        );
    }
}

/// A survey wider than `f32` keeps to a quarter of a millimetre (two sites 40 km apart in UTM
/// coordinates, each point placed to a hundredth of a millimetre) is moved into its parts'
/// frames from the file's `f64` coordinates alike in memory and out of core, as one file and
/// as two tiles.
#[test]
fn a_wide_survey_in_parts_keeps_its_precision_alike_out_of_core() {
    let dir = temp_dir();
    let sphere = common::classified_sphere(8_000);
    let site = |i: usize| DVec3::new(if i.is_multiple_of(2) { 480_000.0 } else { 520_000.0 }, 5_000_000.0, 120.0);
    let fine = |i: usize| DVec3::new((i % 7) as f64, (i % 11) as f64, (i % 13) as f64) * 1e-5;
    let world: Vec<DVec3> =
        sphere.positions.iter().enumerate().map(|(i, p)| site(i) + p.as_dvec3() + fine(i)).collect();
    let cloud = PointCloud { scan: sphere.scan.clone(), ..PointCloud::from_world_positions(&world) };
    let cloud = PointCloud { normals: sphere.normals.clone(), radii: sphere.radii.clone(), ..cloud };
    assert!(cloud.residuals.is_some());
    let whole = [dir.path().join("survey.ply")];
    pointray_io::write_ply(&whole[0], &cloud).unwrap();
    let tiles = [dir.path().join("west.ply"), dir.path().join("east.ply")];
    for (t, path) in tiles.iter().enumerate() {
        // Each tile of both sites, wide as the survey.
        let order: Vec<u32> = (0..cloud.len() as u32).filter(|i| (i / 2) % 2 == t as u32).collect();
        let mut tile = cloud.clone();
        tile.permute(&order);
        pointray_io::write_ply(path, &tile).unwrap();
    }
    let limits = pointray::scene::BuildLimits { chunk_splats: 500, part_splats: 2_000 };
    let settings = pointray::Settings::default();
    for input in [&whole[..], &tiles[..]] {
        let config = pointray::preprocess::PreprocessConfig::default();
        let source = pointray_io::source::load_tiles(input, &config, &Default::default(), &|_| {}).unwrap();
        // Read in memory, the survey keeps what its offsets rounded off (which the parts'
        // frames take, `two_level.rs`'s test), its tiles as well as one file.
        let residuals = source.parts.cloud.residuals.as_ref().expect("a survey wider than f32 keeps");
        assert!(residuals.iter().any(|r| r.length() > 1e-4), "the f32 offsets round by millimetres");
        let scene = pointray::Scene::build_with_limits(source.parts, &settings, limits).unwrap();
        assert!(scene.parts() >= 4, "{} parts", scene.parts());
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        pointray_io::prs::write_prs(&memory, &scene).unwrap();
        let options = pointray_io::prepare::OutOfCore { settings: settings.clone(), limits, ..Default::default() };
        pointray_io::prepare::prepare_out_of_core(input, &streamed, &options, &|_| {}).unwrap();
        let same = std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap();
        assert!(same, "{} inputs: the files differ", input.len());
    }
}

/// Cells smaller than the build's chunks (a small memory budget's) change nothing where the
/// normals and radii are given: each cell lies inside one chunk, and the chunks are the ones a
/// build in memory makes. A sphere with classes and intensities in cells of at most 700 points,
/// filtered, clipped, coloured, its outliers dropped.
#[test]
fn cells_smaller_than_the_chunks_make_the_same_scene_file() {
    use pointray::color_by::ColorBy;
    let dir = temp_dir();
    let cloud = common::classified_sphere(12_000);
    let input = [dir.path().join("sphere.ply")];
    pointray_io::write_ply(&input[0], &cloud).unwrap();
    let cases = [
        (pointray::Settings::default(), None),
        (pointray::Settings { color_by: ColorBy::Intensity, exclude_classes: vec![5], ..Default::default() }, None),
        (pointray::Settings { color_by: ColorBy::Classification, ..Default::default() }, Some(1.0)),
    ];
    for (settings, outlier_std) in cases {
        let config = pointray::preprocess::PreprocessConfig { outlier_std, ..Default::default() };
        let source = pointray_io::source::load_tiles(&input, &config, &Default::default(), &|_| {}).unwrap();
        let scene = pointray::Scene::build(source.parts, &settings).unwrap();
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        pointray_io::prs::write_prs(&memory, &scene).unwrap();
        let options =
            pointray_io::prepare::OutOfCore { preprocess: config, settings, cell_points: 700, ..Default::default() };
        let done = pointray_io::prepare::prepare_out_of_core(&input, &streamed, &options, &|_| {}).unwrap();
        assert_eq!(done.chunks, 1);
        assert!(
            std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(),
            "{outlier_std:?}: the files differ"
        );
    }
}

/// A survey loaded to render is lit by its sun, at the settings' intensity, and a sky, unless
/// a light is named or an environment map lights it alone.
#[test]
fn a_survey_renders_under_its_sun_unless_told_otherwise() {
    use pointray::shading::Light;
    let dir = temp_dir();
    let las = write_file(dir.path(), "a.las", &las_bytes(&survey_points(3_000, |_| 100), false));
    let map = pointray_io::env_map::encode_rgbe(4, 2, &[[0.5; 3]; 8]);
    let map = write_file(dir.path(), "grey.hdr", &map);
    let config = pointray::preprocess::PreprocessConfig::standard();
    let job = |settings: &pointray::Settings| {
        let source = pointray_io::source::load(&las, &config, &Default::default(), &|_| {}).unwrap();
        let mut scene = pointray::Scene::build(source.parts, settings).unwrap();
        scene.set_environment_map(pointray_io::source::environment_map(settings).unwrap());
        scene.job(settings).unwrap().config
    };
    let lights = |settings: &pointray::Settings| job(settings).lights;
    let dimmer = pointray::Settings { light_intensity: 0.5, width: 8, height: 8, ..Default::default() };
    match lights(&dimmer)[..] {
        [Light::Directional { direction, intensity }] => {
            assert_eq!((direction.to_array(), intensity), (pointray_io::SURVEY_SUN, 0.5))
        }
        ref other => panic!("{other:?}"),
    }
    // A sky lights what bounces; camera rays still see the dark background.
    let config = job(&dimmer);
    assert_eq!(config.environment, pointray::shading::Environment::sky(Vec3::Z));
    assert_eq!(config.background, Some(pointray::shading::Environment::BACKGROUND.flat_color()));
    let told = pointray::Settings { light_dir: Some(Vec3::X), ..dimmer.clone() };
    assert!(matches!(lights(&told)[..], [Light::Directional { direction: Vec3::X, .. }]));
    let mapped = pointray::Settings { env_map: Some(map), ..dimmer };
    assert!(lights(&mapped).is_empty());
}

#[test]
fn las_with_full_range_colour_channels_is_read_as_16_bit() {
    let dir = temp_dir();
    let points = survey_points(50, |i| (i * 1000) as u16);
    let loaded = read_cloud(&write_file(dir.path(), "c.las", &las_bytes(&points, false))).unwrap();
    let colors = loaded.cloud.colors.unwrap();
    assert_eq!(colors[1], [1000.0 / 65535.0, 2000.0 / 65535.0, 3000.0 / 65535.0]);
}

#[test]
fn broken_las_files_are_refused_with_their_name() {
    let dir = temp_dir();
    let bytes = las_bytes(&survey_points(500, |_| 100), false);
    // Cut in the points, in the header, and a point count raised past the file.
    write_file(dir.path(), "cut.las", &bytes[..bytes.len() - 700]);
    write_file(dir.path(), "head.las", &bytes[..100]);
    let mut more = bytes.clone();
    more[107..111].copy_from_slice(&1_000_000u32.to_le_bytes()); // legacy point count (LAS 1.2)
    write_file(dir.path(), "count.las", &more);
    let laz = las_bytes(&survey_points(500, |_| 100), true);
    write_file(dir.path(), "cut.laz", &laz[..laz.len() - 300]);
    // A chunk table claiming four billion chunks: the decoder would try to allocate for them.
    let mut chunks = laz.clone();
    let points_at = u32::from_le_bytes(laz[96..100].try_into().unwrap()) as usize;
    let table_at = i64::from_le_bytes(laz[points_at..points_at + 8].try_into().unwrap()) as usize;
    chunks[table_at + 4..table_at + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    write_file(dir.path(), "chunks.laz", &chunks);
    // LAS 1.4's 64-bit count (byte 247) so large that count × record length overflows.
    let fine = las_bytes_of_version(&survey_points(50, |_| 100), false, (1, 4));
    assert_eq!(read_cloud(&write_file(dir.path(), "v14.las", &fine)).unwrap().cloud.len(), 50);
    let mut overflow = las_bytes_of_version(&survey_points(50, |_| 100), false, (1, 4));
    overflow[247..255].copy_from_slice(&u64::MAX.to_le_bytes());
    write_file(dir.path(), "overflow.las", &overflow);
    // The crate reads that count for every 1.4 header, even one whose size field (byte 94)
    // says it is too short to hold it (found by the `cloud` fuzz target).
    overflow[94..96].copy_from_slice(&0u16.to_le_bytes());
    write_file(dir.path(), "overflow-short-header.las", &overflow);
    // An extended VLR (LAS 1.4) declaring 2^60 bytes: the crate would allocate them first.
    let mut evlr = las_bytes_of_version(&survey_points(50, |_| 100), false, (1, 4));
    let start = evlr.len() as u64;
    evlr[235..243].copy_from_slice(&start.to_le_bytes());
    evlr[243..247].copy_from_slice(&1u32.to_le_bytes());
    let mut record = vec![0u8; 60];
    record[20..28].copy_from_slice(&(1u64 << 60).to_le_bytes());
    evlr.extend_from_slice(&record);
    write_file(dir.path(), "evlr.las", &evlr);
    for (name, fragment) in [
        ("cut.las", "more than the file holds"),
        ("head.las", "not a readable LAS file"),
        ("count.las", "more than the file holds"),
        ("cut.laz", "not a readable LAS file"),
        ("chunks.laz", "chunk table claims 4294967295 chunks"),
        ("overflow.las", "declares 18446744073709551615 points of 34 bytes, more than any file can hold"),
        ("overflow-short-header.las", "declares 18446744073709551615 points of 34 bytes"),
        ("evlr.las", "declares 1152921504606846976 bytes; only 0 follow it"),
    ] {
        eprintln!("{}", expect_error(&dir.path().join(name), fragment));
    }
}

// ---------------------------------------------------------------- PCD

fn pcd_header(fields: &str, size: &str, ty: &str, count: &str, width: usize, height: usize, data: &str) -> String {
    format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {ty}\n\
         COUNT {count}\nWIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA {data}\n",
        width * height
    )
}

/// Points of a small organised grid, every third one missing (NaN), colour 0x00RRGGBB.
fn pcd_points() -> Vec<([f32; 3], u32)> {
    (0..12)
        .map(|i| {
            let p = if i % 3 == 2 { [f32::NAN; 3] } else { [i as f32 * 0.1, 1.0 - i as f32 * 0.05, 2.0] };
            (p, 0x0010_2030 + i as u32)
        })
        .collect()
}

/// A `binary_compressed` PCD of `points`: the fields one after another, as LZF literal runs of
/// up to 32 bytes.
fn pcd_compressed(points: &[([f32; 3], u32)]) -> Vec<u8> {
    let mut columns = Vec::new();
    for k in 0..3 {
        points.iter().for_each(|(p, _)| columns.extend_from_slice(&p[k].to_le_bytes()));
    }
    points.iter().for_each(|(_, c)| columns.extend_from_slice(&c.to_le_bytes()));
    let lzf: Vec<u8> = columns.chunks(32).flat_map(|run| [vec![run.len() as u8 - 1], run.to_vec()].concat()).collect();
    let mut bytes =
        pcd_header("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1", points.len(), 1, "binary_compressed").into_bytes();
    bytes.extend_from_slice(&(lzf.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&(columns.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&lzf);
    bytes
}

/// An organised frame's VIEWPOINT is where its sensor stood (kept in the cloud's local
/// coordinates); PCL writes one into every file, so an unorganised cloud's is ignored.
#[test]
fn an_organised_pcd_frame_keeps_its_viewpoint() {
    let dir = temp_dir();
    let rows = "10 20 5\n11 20 5\n10 21 5\n11 21 6\n";
    let frame =
        pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 2, 2, "ascii").replace("VIEWPOINT 0 0 0", "VIEWPOINT 1 2 3");
    let cloud = read_cloud(&write_file(dir.path(), "frame.pcd", (frame + rows).as_bytes())).unwrap().cloud;
    let local = (DVec3::new(1.0, 2.0, 3.0) - cloud.origin).as_vec3();
    assert_eq!((cloud.viewpoints, cloud.viewpoint_of), (vec![local], None));
    // The frame's own up (its sensor's y is down), and the default camera at the sensor.
    let path = dir.path().join("frame.pcd");
    assert_eq!(read_cloud(&path).unwrap().info.up, Some([0.0, -1.0, 0.0]));
    let parts = pointray_io::source::load(&path, &Default::default(), &Default::default(), &|_| {}).unwrap().parts;
    let (view, distance) = parts.view.expect("the sensor's view");
    let bounds = parts.cloud.bounds();
    let eye = parts.cloud.origin + (bounds.center() + view * distance * bounds.diagonal()).as_dvec3();
    assert_close(eye, DVec3::new(1.0, 2.0, 3.0), 1e-4);
    let flat =
        pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 4, 1, "ascii").replace("VIEWPOINT 0 0 0", "VIEWPOINT 1 2 3");
    let flat = read_cloud(&write_file(dir.path(), "flat.pcd", (flat + rows).as_bytes())).unwrap();
    assert!(flat.cloud.viewpoints.is_empty() && flat.info.up.is_none());
}

#[test]
fn pcd_ascii_binary_and_compressed_read_alike_and_drop_nan_points() {
    let dir = temp_dir();
    let points = pcd_points();
    // ascii: a float `rgb` field written as the integer of its bits (as PCL does), and as the
    // float whose bits hold the colour (as others do).
    let mut ascii = pcd_header("x y z rgb", "4 4 4 4", "F F F F", "1 1 1 1", 4, 3, "ascii");
    let mut ascii_float = ascii.clone();
    for (p, c) in &points {
        ascii += &format!("{} {} {} {c}\n", p[0], p[1], p[2]);
        ascii_float += &format!("{} {} {} {:e}\n", p[0], p[1], p[2], f32::from_bits(*c));
    }
    // binary: rows of x y z, a two-value field to skip, rgba as u32.
    let mut binary = pcd_header("x y z extra rgba", "4 4 4 2 4", "F F F I U", "1 1 1 2 1", 4, 3, "binary").into_bytes();
    for (p, c) in &points {
        p.iter().for_each(|v| binary.extend_from_slice(&v.to_le_bytes()));
        binary.extend_from_slice(&[1, 0, 2, 0]);
        binary.extend_from_slice(&c.to_le_bytes());
    }
    let compressed = pcd_compressed(&points);
    let read = |name: &str, bytes: &[u8]| read_cloud(&write_file(dir.path(), name, bytes)).unwrap();
    let clouds = [
        read("a.pcd", ascii.as_bytes()),
        read("f.pcd", ascii_float.as_bytes()),
        read("b.pcd", &binary),
        read("c.pcd", &compressed),
    ];
    let finite: Vec<_> = points.iter().filter(|(p, _)| p[0].is_finite()).collect();
    for loaded in &clouds {
        assert_eq!(loaded.cloud.len(), 8, "{}: the 4 NaN points are dropped", loaded.info.format);
        let world = world_positions(&loaded.cloud);
        let colors = loaded.cloud.colors.as_ref().expect("colour");
        for (i, (p, c)) in finite.iter().enumerate() {
            assert_close(world[i], Vec3::from_array(*p).as_dvec3(), 1e-6);
            let expected = [(c >> 16) & 255, (c >> 8) & 255, c & 255].map(|v| v as f32 / 255.0);
            assert_eq!(colors[i], expected, "{}", loaded.info.format);
        }
    }
    assert_eq!(clouds.map(|l| l.info.format), ["PCD ascii", "PCD ascii", "PCD binary", "PCD binary_compressed"]);
}

#[test]
fn broken_pcd_files_are_refused_with_their_name_and_place() {
    let dir = temp_dir();
    let header = |data: &str| pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 3, 1, data);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("nodata.pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n".to_vec(), "no DATA line"),
        (
            "mismatch.pcd",
            b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n".to_vec(),
            "line 6: FIELDS, SIZE",
        ),
        ("noxyz.pcd", pcd_header("a b c", "4 4 4", "F F F", "1 1 1", 1, 1, "ascii").into_bytes(), "no x, y and z"),
        (
            "type.pcd",
            pcd_header("x y z", "4 4 3", "F F F", "1 1 1", 1, 1, "ascii").into_bytes(),
            "unsupported TYPE F SIZE 3",
        ),
        ("short.pcd", (header("ascii") + "1 2 3\n4 5 6\n").into_bytes(), "declares 3 points, the file holds 2"),
        ("token.pcd", (header("ascii") + "1 2 3\n4 x 6\n7 8 9\n").into_bytes(), "line 13: 'x' is not a number"),
        ("binary.pcd", [header("binary").into_bytes(), vec![0; 30]].concat(), "more than the data holds"),
        (
            "sizes.pcd",
            [header("binary_compressed").into_bytes(), 4u32.to_le_bytes().to_vec(), 99u32.to_le_bytes().to_vec()]
                .concat(),
            "99 bytes uncompressed, the header's points need 36",
        ),
        (
            "version.pcd",
            header("ascii").replace("VERSION 0.7", "VERSION 2.0").into_bytes(),
            "VERSION 2.0: only PCD 0.5 to 0.7",
        ),
        (
            "dotversion.pcd",
            (header("ascii").replace("VERSION 0.7", "VERSION .7") + "1 2 3\n4 5 6\n").into_bytes(),
            "declares 3 points, the file holds 2",
        ),
        (
            "count.pcd",
            pcd_header("x y z", "4 4 4", "F F F", "1 1 18446744073709551615", 1, 1, "ascii").into_bytes(),
            "COUNT 18446744073709551615",
        ),
        (
            "lzf.pcd",
            [
                header("binary_compressed").into_bytes(),
                2u32.to_le_bytes().to_vec(),
                36u32.to_le_bytes().to_vec(),
                vec![0x20, 5],
            ]
            .concat(),
            "back-reference before the start",
        ),
    ];
    for (name, bytes, _) in &cases {
        write_file(dir.path(), name, bytes);
    }
    for (name, _, fragment) in &cases {
        expect_error(&dir.path().join(name), fragment);
    }
}

// ---------------------------------------------------------------- meshes (`pointray sample`)

/// A unit square split as a quad and a triangle over five vertices, an element between the
/// vertices and the faces, and a degenerate two-vertex face.
fn mesh_elements(faces: Vec<Vec<f64>>) -> Vec<Elem> {
    let xyz = |x: f64, y: f64| vec![Val::S(x), Val::S(y), Val::S(0.0)];
    let scalar = |name| Prop::Scalar(Ty::F32, name);
    vec![
        Elem {
            name: "vertex",
            props: vec![scalar("x"), scalar("y"), scalar("z")],
            records: vec![xyz(0.0, 0.0), xyz(1.0, 0.0), xyz(1.0, 1.0), xyz(0.0, 1.0), xyz(2.0, 0.0)],
        },
        Elem { name: "material", props: vec![Prop::Scalar(Ty::U8, "id")], records: vec![vec![Val::S(3.0)]] },
        Elem {
            name: "face",
            props: vec![Prop::Scalar(Ty::U8, "flags"), Prop::List(Ty::U8, Ty::I32, "vertex_indices")],
            records: faces.into_iter().map(|f| vec![Val::S(1.0), Val::L(f)]).collect(),
        },
    ]
}

#[test]
fn meshes_read_alike_in_every_encoding_with_polygons_as_fans() {
    let dir = temp_dir();
    let faces = vec![vec![0.0, 1.0, 2.0, 3.0], vec![1.0, 4.0, 2.0], vec![0.0, 4.0]];
    for (name, encoding) in [("a.ply", Enc::Ascii), ("le.ply", Enc::Le), ("be.ply", Enc::Be)] {
        let path = write_file(dir.path(), name, &encode_ply(encoding, &mesh_elements(faces.clone())));
        let mesh = pointray_io::read_mesh(&path).unwrap();
        assert_eq!(mesh.triangles, [[0, 1, 2], [0, 2, 3], [1, 4, 2]], "{name}");
        assert_eq!((mesh.vertices.len(), mesh.skipped_faces), (5, 1), "{name}");
        let world = world_positions(&mesh.vertices);
        assert_close(world[4], DVec3::new(2.0, 0.0, 0.0), 1e-12);
        // The faces may come first (the format allows any order): the same mesh.
        let mut reordered = mesh_elements(faces.clone());
        reordered.reverse();
        let path = write_file(dir.path(), &format!("first-{name}"), &encode_ply(encoding, &reordered));
        let first = pointray_io::read_mesh(&path).unwrap();
        assert_eq!((first.triangles, first.vertices.positions), (mesh.triangles, mesh.vertices.positions), "{name}");
    }
}

#[test]
fn mesh_errors_name_the_face_and_where_it_is() {
    let dir = temp_dir();
    let bad = vec![vec![0.0, 1.0, 2.0], vec![0.0, 5.0, 2.0]];
    let ascii = write_file(dir.path(), "a.ply", &encode_ply(Enc::Ascii, &mesh_elements(bad.clone())));
    let message = pointray_io::read_mesh(&ascii).unwrap_err().to_string();
    // Header lines 1-14, five vertices, one material: the second face is on line 22.
    assert!(message.ends_with("a.ply: line 22: face 1: vertex index 5 is not one of the 5 vertices"), "{message}");
    let binary = write_file(dir.path(), "b.ply", &encode_ply(Enc::Le, &mesh_elements(bad)));
    let message = pointray_io::read_mesh(&binary).unwrap_err().to_string();
    assert!(message.contains("b.ply: byte ") && message.contains("face 1: vertex index 5"), "{message}");

    let cloud = write_file(dir.path(), "cloud.ply", &encode_ply(Enc::Le, &mesh_elements(vec![])[..1]));
    let message = pointray_io::read_mesh(&cloud).unwrap_err().to_string();
    assert!(message.ends_with("cloud.ply: no 'face' element: not a mesh"), "{message}");
    let text = write_file(dir.path(), "c.xyz", b"0 0 0\n");
    assert!(
        pointray_io::read_mesh(&text)
            .unwrap_err()
            .to_string()
            .ends_with("c.xyz: not a mesh: PLY with faces, OFF or OBJ")
    );
    let mut truncated = encode_ply(Enc::Le, &mesh_elements(vec![vec![0.0, 1.0, 2.0]]));
    truncated.truncate(truncated.len() - 3);
    let path = write_file(dir.path(), "t.ply", &truncated);
    let message = pointray_io::read_mesh(&path).unwrap_err().to_string();
    assert!(message.contains("t.ply: byte") && message.contains("face 0"), "{message}");
}

// ---------------------------------------------------------------- E57

/// Two scans in one E57 file: one Cartesian with colours and a pose (moved 10 along x, turned
/// a quarter about z), one spherical with invalid points and no pose.
fn e57_two_scans() -> Vec<u8> {
    use e57::{E57Writer, Quaternion, Record, RecordValue, Transform, Translation};
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut writer = E57Writer::new(&mut bytes, "file").unwrap();
    let prototype = vec![
        Record::CARTESIAN_X_F64,
        Record::CARTESIAN_Y_F64,
        Record::CARTESIAN_Z_F64,
        Record::COLOR_RED_U8,
        Record::COLOR_GREEN_U8,
        Record::COLOR_BLUE_U8,
    ];
    let mut scan = writer.add_pointcloud("scan-a", prototype).unwrap();
    let half = std::f64::consts::FRAC_1_SQRT_2;
    scan.set_transform(Some(Transform {
        rotation: Quaternion { w: half, x: 0.0, y: 0.0, z: half },
        translation: Translation { x: 10.0, y: 0.0, z: 0.0 },
    }));
    for (x, red) in [(1.0, 255), (2.0, 0)] {
        let d = RecordValue::Double;
        scan.add_point(vec![
            d(x),
            d(0.0),
            d(0.0),
            RecordValue::Integer(red),
            RecordValue::Integer(0),
            RecordValue::Integer(0),
        ])
        .unwrap();
    }
    scan.finalize().unwrap();
    let prototype = vec![
        Record::SPHERICAL_RANGE_F64,
        Record::SPHERICAL_AZIMUTH_F64,
        Record::SPHERICAL_ELEVATION_F64,
        Record::SPHERICAL_INVALID_STATE,
    ];
    let mut scan = writer.add_pointcloud("scan-b", prototype).unwrap();
    // Eight points, five of them directions without a range (with only the first three, the
    // `e57` crate's reader failed: "Cannot read next point because of logic error").
    let mut points = vec![(2.0, 0.0, 0), (3.0, std::f64::consts::FRAC_PI_2, 0), (5.0, 0.0, 2)];
    points.extend((0..5).map(|i| (4.0, f64::from(i), 1)));
    for (range, azimuth, invalid) in points {
        let d = RecordValue::Double;
        scan.add_point(vec![d(range), d(azimuth), d(0.0), RecordValue::Integer(invalid)]).unwrap();
    }
    scan.finalize().unwrap();
    writer.finalize().unwrap();
    drop(writer);
    bytes.into_inner()
}

#[test]
fn e57_scans_are_read_with_their_poses_and_invalid_points_left_out() {
    let dir = temp_dir();
    let path = write_file(dir.path(), "two.e57", &e57_two_scans());
    let loaded = read_cloud(&path).unwrap();
    assert_eq!((loaded.info.format.as_str(), loaded.info.up), ("E57, 2 scans", Some([0.0, 0.0, 1.0])));
    let world = world_positions(&loaded.cloud);
    assert_eq!(world.len(), 4, "the invalid and the direction-only points are left out");
    // (1, 0, 0) turned a quarter about z is (0, 1, 0), then moved to (10, 1, 0).
    assert_close(world[0], DVec3::new(10.0, 1.0, 0.0), 1e-9);
    assert_close(world[1], DVec3::new(10.0, 2.0, 0.0), 1e-9);
    // Range 2 straight ahead, range 3 a quarter turn to the left.
    assert_close(world[2], DVec3::new(2.0, 0.0, 0.0), 1e-9);
    assert_close(world[3], DVec3::new(0.0, 3.0, 0.0), 1e-9);
    let colors = loaded.cloud.colors.unwrap();
    assert_eq!((colors[0], colors[1]), ([1.0, 0.0, 0.0], [0.0, 0.0, 0.0]));
    // The Cartesian scan's pose places no scanner: the spanning tree orients the normals.
    assert!(loaded.cloud.viewpoints.is_empty());
}

/// A thin wall (the plane x = 0, 1 cm thick) scanned from both sides: two spherical scans,
/// their scanners posed at x = −5 and x = +5.
fn e57_wall_from_both_sides() -> Vec<u8> {
    use e57::{E57Writer, Quaternion, Record, RecordValue, Transform, Translation};
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut writer = E57Writer::new(&mut bytes, "wall").unwrap();
    for (side, x) in [(-5.0f64, 5.0f64), (5.0, -4.99)] {
        let prototype =
            vec![Record::SPHERICAL_RANGE_F64, Record::SPHERICAL_AZIMUTH_F64, Record::SPHERICAL_ELEVATION_F64];
        let mut scan = writer.add_pointcloud(&format!("from {side}"), prototype).unwrap();
        let identity = Quaternion { w: 1.0, x: 0.0, y: 0.0, z: 0.0 };
        scan.set_transform(Some(Transform {
            rotation: identity,
            translation: Translation { x: side, y: 0.0, z: 0.0 },
        }));
        // The wall in the scanner's frame: x fixed, y and z on a 30 × 30 grid over 2 m.
        for i in 0..900 {
            let (y, z) = (f64::from(i % 30) / 15.0 - 1.0, f64::from(i / 30) / 15.0 - 1.0);
            let range = (x * x + y * y + z * z).sqrt();
            let d = RecordValue::Double;
            scan.add_point(vec![d(range), d(y.atan2(x)), d((z / range).asin())]).unwrap();
        }
        scan.finalize().unwrap();
    }
    writer.finalize().unwrap();
    drop(writer);
    bytes.into_inner()
}

#[test]
fn each_e57_scan_keeps_its_scanner_to_face() {
    let dir = temp_dir();
    let loaded = read_cloud(&write_file(dir.path(), "wall.e57", &e57_wall_from_both_sides())).unwrap();
    let cloud = loaded.cloud;
    let world: Vec<DVec3> = cloud.viewpoints.iter().map(|v| cloud.origin + v.as_dvec3()).collect();
    assert_close(world[0], DVec3::new(-5.0, 0.0, 0.0), 1e-6);
    assert_close(world[1], DVec3::new(5.0, 0.0, 0.0), 1e-6);
    let of = cloud.viewpoint_of.as_ref().unwrap();
    assert_eq!((of.len(), of[0], of[899], of[900]), (1800, 0, 0, 1));
    // Each side faces its own scanner (scan 0's sheet at x = 0 faces −x, scan 1's at x = 0.01
    // faces +x); a spanning tree over the two sheets gets one of them wrong.
    let wrong_sides = |mut cloud: PointCloud| {
        pointray::preprocess::preprocess(&mut cloud, &pointray::preprocess::PreprocessConfig::standard()).unwrap();
        let origin_x = cloud.origin.x;
        let facing = |(p, n): (&Vec3, &Vec3)| (n.x > 0.99) == (origin_x + f64::from(p.x) > 0.005);
        cloud.positions.iter().zip(cloud.normals.as_ref().unwrap()).filter(|&pn| !facing(pn)).count()
    };
    let blind = PointCloud { viewpoints: Vec::new(), viewpoint_of: None, ..cloud.clone() };
    assert_eq!((wrong_sides(cloud), wrong_sides(blind)), (0, 900));
}

#[test]
fn a_corrupt_e57_page_is_refused_by_its_checksum() {
    let dir = temp_dir();
    let mut bytes = e57_two_scans();
    // The first page's data (its checksum is its last four of 1,024 bytes).
    bytes[100] ^= 0x40;
    let message = expect_error(&write_file(dir.path(), "bad.e57", &bytes), "checksum");
    assert!(message.starts_with(&format!("{}", dir.path().join("bad.e57").display())), "{message}");
}

/// E57 files read as streams out of core give the scene files read whole give: scans with their
/// poses, invalid points left out, each scan's points facing its own scanner (the wall), colours
/// and intensities, real files.
#[test]
fn e57_files_prepare_out_of_core_as_in_memory() {
    let dir = temp_dir();
    let files = [
        write_file(dir.path(), "wall.e57", &e57_wall_from_both_sides()),
        write_file(dir.path(), "two.e57", &e57_two_scans()),
        real_file("tinyCartesianFloatRgb.e57"),
        real_file("tiny_spherical.e57"),
    ];
    let config = pointray::preprocess::PreprocessConfig::standard();
    for file in files {
        let input = std::slice::from_ref(&file);
        let (memory, streamed) = (dir.path().join("memory.prs"), dir.path().join("streamed.prs"));
        let source = pointray_io::source::load_tiles(input, &config, &Default::default(), &|_| {}).unwrap();
        let scene = pointray::Scene::build(source.parts, &pointray::Settings::default()).unwrap();
        pointray_io::prs::write_prs(&memory, &scene).unwrap();
        let options = pointray_io::prepare::OutOfCore { preprocess: config, ..Default::default() };
        pointray_io::prepare::prepare_out_of_core(input, &streamed, &options, &|_| {}).unwrap();
        assert!(
            std::fs::read(&memory).unwrap() == std::fs::read(&streamed).unwrap(),
            "{}: the files differ",
            file.display()
        );
    }
}

/// A file the crate's tests keep (`tests/data/README.md` gives each one's origin and licence).
fn real_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

#[test]
fn real_e57_files_read_with_their_points_and_colours() {
    // Cartesian floats with colour, far from the origin: recentred, every point kept.
    let rgb = read_cloud(&real_file("tinyCartesianFloatRgb.e57")).unwrap();
    assert_eq!((rgb.cloud.len(), rgb.info.format.as_str()), (2090, "E57, 1 scan"));
    let colors = rgb.cloud.colors.as_ref().expect("the scan has colour");
    assert!(colors.iter().flatten().all(|c| (0.0..=1.0).contains(c)) && colors.iter().any(|c| c[0] != c[1]));
    assert!(world_positions(&rgb.cloud).iter().all(|p| (295.0..299.0).contains(&p.z)));
    // Spherical coordinates, converted: the points lie within their ranges of the scanner.
    let spherical = read_cloud(&real_file("tiny_spherical.e57")).unwrap();
    assert_eq!(spherical.cloud.len(), 180);
    assert!(world_positions(&spherical.cloud).iter().all(|p| p.length() <= 1.0 + 1e-6 && p.is_finite()));
    // Intensity without colour shows as grey, and is kept, normalised by the file's limits.
    let intensity = read_cloud(&real_file("scaled_integer_intensity.e57")).unwrap();
    assert_eq!(intensity.cloud.len(), 2);
    assert!(intensity.cloud.colors.unwrap().iter().all(|c| c[0] == c[1] && c[1] == c[2]));
    let values = intensity.cloud.scan.intensity.expect("the scan has intensity");
    assert!(values.iter().all(|v| (0.0..=1.0).contains(v)) && values[0] != values[1], "{values:?}");
    let message = expect_error(&real_file("corrupt_crc.e57"), "invalid checksum");
    assert!(message.contains("corrupt_crc.e57: not a readable E57 file"), "{message}");
}

/// The distinct values of a column, in order.
fn distinct<T: Copy + PartialOrd>(values: &[T]) -> Vec<T> {
    let mut values = values.to_vec();
    values.sort_by(|a, b| a.partial_cmp(b).unwrap());
    values.dedup();
    values
}

#[test]
fn real_las_files_keep_their_scan_attributes() {
    // (file, format, points, classes, distinct intensities and GPS times, returns), the last
    // three as laspy 2.7 with lazrs 0.8 reads them: LAS 1.1 to 1.4, point formats 1, 4, 6, 7
    // and 10, a COPC file (LAZ 1.4, its points in octree order) and class 12 (overlap) in a
    // legacy format.
    let files = [
        ("simple1_1.las", "LAS 1.1, point format 1", 1065, vec![1, 2], (214, 1065), 4),
        ("1.2-empty-geotiff-vlrs.las", "LAS 1.2, point format 1", 43, vec![0], (1, 43), 2),
        ("mvk-thin.las", "LAS 1.2, point format 1", 6280, vec![1, 2, 4, 5, 9, 12], (221, 6280), 4),
        ("simple1_3.las", "LAS 1.3, point format 4", 999, vec![1], (187, 999), 1),
        ("test1_4.las", "LAS 1.4, point format 6", 1000, vec![2], (61, 1000), 4),
        ("autzen-bmx-2010.las", "LAS 1.4, point format 7", 829, vec![2], (206, 357), 4),
        ("simple.copc.laz", "LAZ 1.4, point format 7", 1065, vec![1, 2], (214, 1065), 4),
        ("fullwave.laz", "LAZ 1.4, point format 10", 10_750, vec![0], (5969, 7124), 9),
    ];
    for (name, format, points, classes, (intensities, times), most_returns) in files {
        let loaded = read_cloud(&real_file(name)).unwrap();
        assert_eq!((loaded.info.format.as_str(), loaded.cloud.len()), (format, points), "{name}");
        let scan = &loaded.cloud.scan;
        assert_eq!(distinct(scan.classification.as_ref().unwrap()), classes, "{name}");
        assert_eq!(distinct(scan.intensity.as_ref().unwrap()).len(), intensities, "{name}");
        assert_eq!(distinct(scan.gps_time.as_ref().unwrap()).len(), times, "{name}");
        let returns = distinct(scan.return_number.as_ref().unwrap());
        assert_eq!(returns, (1..=most_returns).collect::<Vec<u8>>(), "{name}");
        for property in ["intensity", "classification", "return_number", "gps_time"] {
            assert!(loaded.info.vertex_properties.contains(&property.to_string()), "{name}: {property}");
        }
    }
    // Formats 7 and 10 have colour, 1, 4 and 6 none; a colour format whose writer filled in
    // zeros (laspy's plane.laz) has none either, rather than a black model.
    for (name, coloured) in
        [("simple.copc.laz", true), ("fullwave.laz", true), ("test1_4.las", false), ("plane.laz", false)]
    {
        let colors = read_cloud(&real_file(name)).unwrap().cloud.colors;
        assert_eq!(colors.is_some(), coloured, "{name}");
        assert!(colors.is_none_or(|c| c.iter().flatten().any(|&v| v > 0.2)), "{name}");
    }
}

#[test]
fn real_meshes_and_text_files_read_right() {
    // OFF with comments and face colours; OBJ with float vertex colours, and with a NaN one.
    let off = pointray_io::read_mesh(&real_file("comments.off")).unwrap();
    assert_eq!((off.vertices.len(), off.triangles.len()), (8, 12), "six quads, two triangles each");
    let obj = pointray_io::read_mesh(&real_file("reference.obj")).unwrap();
    assert_eq!((obj.vertices.len(), obj.triangles.len()), (845, 1610));
    let colors = obj.vertices.colors.as_ref().unwrap();
    assert!(
        colors.iter().flatten().all(|c| (0.0..=1.0).contains(c))
            && distinct(&colors.iter().map(|c| c[0]).collect::<Vec<_>>()).len() > 50
    );
    let nan = read_cloud(&real_file("nancolor.obj")).unwrap().cloud;
    assert!(nan.colors.unwrap().iter().flatten().all(|c| (0.0..=1.0).contains(c)), "NaN read as 0");
    // PLY with its faces before its vertices, ASCII and binary alike: five Platonic solids.
    let ascii = pointray_io::read_mesh(&real_file("platonic_shelf_ascii.ply")).unwrap();
    let binary = pointray_io::read_mesh(&real_file("platonic_shelf.ply")).unwrap();
    assert_eq!((ascii.vertices.len(), ascii.triangles.len()), (50, 4 + 12 + 8 + 36 + 20));
    assert_eq!((ascii.vertices.positions, ascii.triangles), (binary.vertices.positions, binary.triangles));
    // CloudCompare's x y z R G B A (float channels) and Agisoft's x y z r g b: the same colours.
    let cc = read_cloud(&real_file("points_cloudcompare.xyz")).unwrap();
    assert_eq!(cc.info.vertex_properties.last().map(String::as_str), Some("alpha"));
    let agisoft = read_cloud(&real_file("points_agisoft.xyz")).unwrap().cloud;
    let [cc, agisoft] = [cc.cloud.colors.unwrap(), agisoft.colors.unwrap()];
    assert_eq!((cc.len(), agisoft.len()), (101, 100));
    assert_eq!((cc[0], agisoft[0]), ([117.0 / 255.0, 73.0 / 255.0, 49.0 / 255.0], cc[0]));
}

#[test]
fn real_pcd_files_read_right() {
    // PCL's: binary with packed rgb and normals (1000 rows of one column), and a compressed
    // unorganised one with rgba.
    let colored = read_cloud(&real_file("colored_cloud.pcd")).unwrap().cloud;
    assert_eq!(colored.len(), 1000);
    assert!(colored.normals.unwrap().iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
    assert!(colored.colors.unwrap().iter().any(|c| c[0] != c[2]));
    let milk = read_cloud(&real_file("milk_color.pcd")).unwrap();
    assert_eq!((milk.info.format.as_str(), milk.cloud.len()), ("PCD binary_compressed", 13_704));
    // PDAL's: upper-case X Y Z, its attribute names, 16-bit colour channels; the same points
    // as laspy's simple1_1.las (the Autzen sample), classes and all.
    let pdal = read_cloud(&real_file("autzen-utm.pcd")).unwrap().cloud;
    assert_eq!(pdal.len(), 1065);
    assert_eq!(distinct(pdal.scan.classification.as_ref().unwrap()), vec![1, 2]);
    assert!(pdal.scan.gps_time.is_some() && pdal.scan.return_number.is_some());
    let colors = pdal.colors.unwrap();
    assert!(colors.iter().flatten().all(|c| (0.0..=1.0).contains(c)) && colors.iter().flatten().any(|&c| c > 0.5));
}

#[test]
fn ply_keeps_scan_attributes_and_the_up_axis() {
    let dir = temp_dir();
    let (_, mut cloud) = sample_cloud(20, DVec3::ZERO);
    cloud.scan = ScanAttributes {
        intensity: Some((0..20).map(|i| i as f32 * 100.5).collect()),
        classification: Some((0..20).map(|i| [2, 6, 9][i % 3]).collect()),
        return_number: Some((0..20).map(|i| 1 + (i % 4) as u8).collect()),
        gps_time: Some((0..20).map(|i| 3.5e8 + f64::from(i) * 1e-6).collect()),
    };
    let path = dir.path().join("scan.ply");
    let axes = Axes { up: Some([0.0, 0.0, 1.0]), sun: Some(pointray_io::SURVEY_SUN) };
    write_ply_with_axes(&path, &cloud, axes).unwrap();
    let loaded = read_cloud(&path).unwrap();
    assert_eq!((loaded.info.up, loaded.info.sun), (axes.up, axes.sun));
    let (read, truth) = (&loaded.cloud.scan, &cloud.scan);
    assert_eq!(read.intensity, truth.intensity);
    assert_eq!(read.classification, truth.classification);
    assert_eq!(read.return_number, truth.return_number);
    assert_eq!(read.gps_time, truth.gps_time, "GPS time keeps its microseconds (double)");
    // Without an up axis, none comes back; a sensor's position comes back as it went.
    cloud.viewpoints = vec![Vec3::new(0.5, -2.0, 3.0)];
    write_ply(&path, &cloud).unwrap();
    let loaded = read_cloud(&path).unwrap();
    assert_eq!(loaded.info.up, None);
    let sensor = loaded.cloud.origin + loaded.cloud.viewpoints[0].as_dvec3();
    assert_close(sensor, cloud.origin + DVec3::new(0.5, -2.0, 3.0), 1e-6);
}

#[test]
fn scan_attributes_are_found_under_other_tools_names() {
    let dir = temp_dir();
    // CloudCompare's scalar fields, and a 4-column XYZ file's intensity.
    let ply = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
               property float scalar_Intensity\nproperty float scalar_Classification\n\
               property float scalar_Return_Number\nproperty double scalar_GpsTime\nend_header\n\
               0 0 0 12.5 6 1 100.25\n1 0 0 40 2 3 200.5\n";
    let scan = read_cloud(&write_file(dir.path(), "cc.ply", ply.as_bytes())).unwrap().cloud.scan;
    assert_eq!(scan.intensity, Some(vec![12.5, 40.0]));
    assert_eq!(scan.classification, Some(vec![6, 2]));
    assert_eq!(scan.return_number, Some(vec![1, 3]));
    assert_eq!(scan.gps_time, Some(vec![100.25, 200.5]));
    let xyz = read_cloud(&write_file(dir.path(), "i.xyz", b"0 0 0 7\n1 0 0 -3\n")).unwrap().cloud;
    assert_eq!((xyz.scan.intensity, xyz.colors), (Some(vec![7.0, -3.0]), None));
}
