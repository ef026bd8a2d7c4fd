//! `discard_unfinished_writes`, what a Ctrl-C handler calls. In its own test binary: it
//! deletes the temporary files of every write in the process, which would break other tests'
//! writes running beside it.

use pointray_io::{atomic_write, discard_unfinished_writes};

fn entries(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

#[test]
fn an_interrupt_mid_write_leaves_nothing_and_spares_finished_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let done = dir.path().join("done.png");
    atomic_write(&done, |w| w.write_all(b"finished")).unwrap();

    let target = dir.path().join("out.png");
    let result = atomic_write(&target, |w| {
        w.write_all(&[7; 100_000])?;
        w.flush()?;
        let during = entries(dir.path());
        assert_eq!(during.len(), 2, "the temporary file exists while writing: {during:?}");
        assert!(during[0].starts_with(".out.png.") && during[0].ends_with(".tmp"), "{during:?}");
        // What the Ctrl-C handler does before it exits.
        discard_unfinished_writes();
        assert_eq!(entries(dir.path()), ["done.png"]);
        Err(std::io::Error::other("interrupted"))
    });
    assert!(result.is_err());
    assert_eq!(entries(dir.path()), ["done.png"]);
    assert_eq!(std::fs::read(&done).unwrap(), b"finished");

    // Nothing is pending any more: a later discard deletes nothing, a later write works.
    discard_unfinished_writes();
    atomic_write(&target, |w| w.write_all(b"again")).unwrap();
    discard_unfinished_writes();
    assert_eq!(entries(dir.path()), ["done.png", "out.png"]);
}
