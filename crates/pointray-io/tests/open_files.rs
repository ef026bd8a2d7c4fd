//! Preparing out of core writes a file a cell at once: it raises the soft limit on open files to
//! what its cells take, and where the hard limit stands in the way says so, naming the limit.
//! (A test binary of its own: it lowers its process's limits for good.)

mod common;

#[test]
fn the_open_files_limit_is_raised_to_the_cells_or_named() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = common::classified_sphere(20_000);
    let input = [dir.path().join("sphere.ply")];
    pointray_io::write_ply(&input[0], &cloud).unwrap();
    // Cells of at most 100 points: some 200 files at once, past a soft limit of 64.
    let options = pointray_io::prepare::OutOfCore { cell_points: 100, ..Default::default() };
    let (_, hard) = rlimit::Resource::NOFILE.get().unwrap();
    rlimit::Resource::NOFILE.set(64, hard).unwrap();
    let output = dir.path().join("sphere.prs");
    let done = pointray_io::prepare::prepare_out_of_core(&input, &output, &options, &|_| {});
    assert!(done.is_ok(), "{:?}", done.err());
    // Raised to the cells' files and the others' 64: more than 100 cells, which a limit of 64
    // could not have held open.
    let raised = rlimit::Resource::NOFILE.get().unwrap().0;
    assert!(raised > 64 + 100, "raised to {raised}");
    // A hard limit below what the cells take: refused, the limit named, no file left.
    rlimit::Resource::NOFILE.set(64, 64).unwrap();
    let output = dir.path().join("refused.prs");
    let err = pointray_io::prepare::prepare_out_of_core(&input, &output, &options, &|_| {}).unwrap_err().to_string();
    assert!(err.contains("may open 64 files") && err.contains("ulimit -n"), "{err}");
    assert!(!output.exists());
}
