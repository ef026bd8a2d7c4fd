//! MP4 video (H.264) from rendered frames, through ffmpeg (Debian's package; `$POINTRAY_FFMPEG`
//! names another): fed 8-bit sRGB frames on its standard input as they come, and written whole
//! or not at all (into a scratch directory beside the output, which an error, a drop or an
//! interrupt removes, renamed into place when ffmpeg succeeds).

use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use crate::IoError;

/// The ffmpeg to encode with (`$POINTRAY_FFMPEG`, else `ffmpeg`), if it runs.
pub fn ffmpeg() -> Option<String> {
    let program = std::env::var("POINTRAY_FFMPEG").unwrap_or_else(|_| "ffmpeg".into());
    let runs = Command::new(&program).arg("-version").output().is_ok_and(|o| o.status.success());
    runs.then_some(program)
}

/// What to say where ffmpeg is missing.
pub const NO_FFMPEG: &str = "ffmpeg not found (Debian: apt-get install ffmpeg; or set POINTRAY_FFMPEG)";

/// An MP4 being written, a frame at a time.
pub struct Mp4Writer {
    output: PathBuf,
    program: String,
    frame_bytes: usize,
    child: Child,
    stdin: Option<ChildStdin>,
    /// ffmpeg's messages (a file, not a pipe: a full pipe would stall it while we write).
    messages: std::fs::File,
    /// Where ffmpeg writes (`video.mp4` in it), renamed to `output` at the end.
    scratch: crate::ScratchDir,
}

impl Mp4Writer {
    /// Starts `program` (see [`ffmpeg`]) encoding frames of `width`×`height` at `fps` a second
    /// into `output`.
    pub fn create(program: &str, output: &Path, width: u32, height: u32, fps: f32) -> Result<Self, IoError> {
        let fail = |e| IoError::io(output, e);
        if !(fps.is_finite() && fps > 0.0) || width == 0 || height == 0 {
            return Err(IoError::invalid(output, format!("a video of {width}×{height} at {fps} frames a second")));
        }
        let scratch = crate::ScratchDir::beside(output)?;
        let messages = tempfile::tempfile().map_err(fail)?;
        let mut child = Command::new(program)
            .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{width}x{height}"), "-framerate", &fps.to_string(), "-i", "-"])
            // H.264 in 4:2:0 wants even sizes: an odd frame gets a last row or column.
            .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-f", "mp4"])
            .arg(scratch.path().join("video.mp4"))
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(messages.try_clone().map_err(fail)?)
            .spawn()
            .map_err(|e| IoError::io(output, std::io::Error::new(e.kind(), format!("{program}: {e}"))))?;
        let stdin = child.stdin.take();
        let (output, program) = (output.to_path_buf(), program.to_string());
        let frame_bytes = width as usize * height as usize * 3;
        Ok(Self { output, program, frame_bytes, child, stdin, messages, scratch })
    }

    /// Adds a frame: 8-bit sRGB, row-major, top row first (`Frame::srgb8`).
    pub fn push(&mut self, srgb8: &[u8]) -> Result<(), IoError> {
        if srgb8.len() != self.frame_bytes {
            let (len, want) = (srgb8.len(), self.frame_bytes);
            return Err(IoError::invalid(
                &self.output,
                format!("a frame of {len} bytes where the video's take {want}"),
            ));
        }
        let Some(stdin) = self.stdin.as_mut() else {
            return Err(IoError::invalid(&self.output, format!("{} stopped before", self.program)));
        };
        match stdin.write_all(srgb8) {
            Ok(()) => Ok(()),
            // ffmpeg stopped: its own words say why.
            Err(_) => Err(self.failure()),
        }
    }

    /// Ends the video and puts it in place.
    pub fn finish(mut self) -> Result<(), IoError> {
        drop(self.stdin.take());
        let status = self.child.wait().map_err(|e| IoError::io(&self.output, e))?;
        if !status.success() {
            return Err(self.failure());
        }
        let video = self.scratch.path().join("video.mp4");
        let synced = std::fs::File::open(&video).and_then(|f| f.sync_all());
        synced.and_then(|()| std::fs::rename(&video, &self.output)).map_err(|e| IoError::io(&self.output, e))
    }

    /// Why ffmpeg failed, once it has ended.
    fn failure(&mut self) -> IoError {
        drop(self.stdin.take());
        let _ = self.child.wait();
        let mut said = String::new();
        let _ = self.messages.rewind().and_then(|()| self.messages.read_to_string(&mut said));
        IoError::invalid(&self.output, format!("{} failed: {}", self.program, said.trim()))
    }
}

impl Drop for Mp4Writer {
    fn drop(&mut self) {
        // Dropped before `finish` (an error, an interruption): no video.
        if self.stdin.take().is_some() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A failing encoder's words and no file; a video where ffmpeg is installed (`.ci/run`
    /// installs it on a fresh machine).
    #[test]
    fn frames_become_a_video_whole_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("v.mp4");
        let refused = Mp4Writer::create("false", &out, 4, 4, 0.0).err().expect("refused").to_string();
        assert!(refused.contains("frames a second"), "{refused}");
        let missing = Mp4Writer::create("/nonexistent/ffmpeg", &out, 4, 4, 24.0).err().expect("refused");
        assert!(matches!(&missing, IoError::Io { io, .. } if io.kind() == std::io::ErrorKind::NotFound), "{missing}");
        let mut failing = Mp4Writer::create("false", &out, 5, 3, 24.0).unwrap();
        let frame = vec![128; 5 * 3 * 3];
        let err = match (0..64).try_for_each(|_| failing.push(&frame)) {
            Ok(()) => failing.finish().unwrap_err(),
            Err(e) => {
                let again = failing.push(&frame).unwrap_err().to_string();
                assert!(again.contains("stopped before"), "{again}");
                drop(failing);
                e
            }
        };
        assert!(err.to_string().contains("false failed"), "{err}");
        assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none(), "nothing left");
        let Some(program) = ffmpeg() else {
            eprintln!("ffmpeg not installed: the video itself is not checked");
            return;
        };
        let mut video = Mp4Writer::create(&program, &out, 5, 3, 24.0).unwrap();
        assert!(video.push(&frame[1..]).unwrap_err().to_string().contains("44 bytes"));
        for k in 0..3u8 {
            video.push(&[k * 100; 5 * 3 * 3]).unwrap();
        }
        video.finish().unwrap();
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[4..8], b"ftyp", "an MP4");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "the video alone");
    }
}
