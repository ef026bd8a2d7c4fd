//! `discard_unfinished_writes_then`, what a Ctrl-C handler calls. In its own test binary: it
//! deletes the temporary files of every write in the process and stops all writing, which
//! would break other tests' writes running beside it.

use std::io::ErrorKind;

use pointray_io::{IoError, atomic_write, discard_unfinished_writes_then};

fn entries(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

fn is_interrupted(result: Result<(), IoError>) -> bool {
    matches!(result, Err(IoError::Io { io, .. }) if io.kind() == ErrorKind::Interrupted)
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
        // What the Ctrl-C handler does, on its own thread; here "exiting" unwinds instead.
        let handler = std::thread::spawn(|| discard_unfinished_writes_then(|| panic!("the process would end here")));
        assert!(handler.join().is_err());
        assert_eq!(entries(dir.path()), ["done.png"]);
        // The write itself goes on to the end: only the rename is refused.
        Ok(())
    });
    assert!(is_interrupted(result));
    assert_eq!(entries(dir.path()), ["done.png"]);
    assert_eq!(std::fs::read(&done).unwrap(), b"finished");

    // Writing has stopped: a later write fails before it creates anything.
    assert!(is_interrupted(atomic_write(&target, |w| w.write_all(b"again"))));
    assert_eq!(entries(dir.path()), ["done.png"]);
}
