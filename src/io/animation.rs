//! An animated GIF built one frame at a time while a run goes on (the `gif` crate; each frame gets its
//! own 256-colour palette by NeuQuant), written under a temporary name and renamed into place when it
//! is finished, so that a run that fails leaves no file that looks complete.

use crate::error::{io_err, Error, Result};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// An animated GIF being written: frames of one size, shown `delay` hundredths of a second each, looped.
pub struct Animation {
    path: PathBuf,
    partial: PathBuf,
    size: (u16, u16),
    delay: u16,
    encoder: Option<gif::Encoder<BufWriter<File>>>,
    frames: usize,
}

impl Animation {
    /// An animation to be written to `path`, of frames `size` pixels, each shown `delay` hundredths of
    /// a second. Nothing is written before the first frame.
    pub fn new(path: &Path, size: (u32, u32), delay: u16) -> Result<Self> {
        let fit = |v: u32| {
            u16::try_from(v).map_err(|_| {
                Error::Io(format!(
                    "{}: a frame of {v} pixels is too large for a GIF",
                    path.display()
                ))
            })
        };
        let mut partial = path.as_os_str().to_owned();
        partial.push(".partial");
        Ok(Animation {
            path: path.to_path_buf(),
            partial: PathBuf::from(partial),
            size: (fit(size.0)?, fit(size.1)?),
            delay,
            encoder: None,
            frames: 0,
        })
    }

    /// Appends a frame (RGB, 3 bytes per pixel, rows from the top, of the animation's size).
    pub fn push(&mut self, rgb: &[u8]) -> Result<()> {
        let (w, h) = self.size;
        if rgb.len() != w as usize * h as usize * 3 {
            return Err(Error::Io(format!(
                "{}: a frame of {} bytes for {w} x {h} pixels",
                self.path.display(),
                rgb.len()
            )));
        }
        let gif_err = |e: gif::EncodingError| Error::Io(format!("{}: {e}", self.partial.display()));
        if self.encoder.is_none() {
            let file = File::create(&self.partial).map_err(|e| io_err(&self.partial, e))?;
            let mut enc = gif::Encoder::new(BufWriter::new(file), w, h, &[]).map_err(gif_err)?;
            enc.set_repeat(gif::Repeat::Infinite).map_err(gif_err)?;
            self.encoder = Some(enc);
        }
        // Speed 10 of 1-30: NeuQuant's usual trade of quality against time (tens of ms per frame here).
        let mut frame = gif::Frame::from_rgb_speed(w, h, rgb, 10);
        frame.delay = self.delay;
        self.encoder
            .as_mut()
            .expect("created above")
            .write_frame(&frame)
            .map_err(gif_err)?;
        self.frames += 1;
        Ok(())
    }

    /// Frames written so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Ends the file and moves it into place when it has at least `min_frames` frames; otherwise
    /// removes what was written. Returns whether the file was kept.
    pub fn finish(mut self, min_frames: usize) -> Result<bool> {
        let Some(enc) = self.encoder.take() else {
            return Ok(false);
        };
        let writer = enc.into_inner().map_err(|e| io_err(&self.partial, e))?;
        writer.into_inner().map_err(|e| io_err(&self.partial, e.into_error()))?;
        if self.frames < min_frames {
            std::fs::remove_file(&self.partial).map_err(|e| io_err(&self.partial, e))?;
            return Ok(false);
        }
        std::fs::rename(&self.partial, &self.path).map_err(|e| io_err(&self.path, e))?;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_come_back_in_order_and_short_animations_are_removed() {
        let dir = std::env::temp_dir().join(format!("blockflow-animation-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.gif");
        let (w, h) = (8u32, 4u32);
        let mut a = Animation::new(&path, (w, h), 20).unwrap();
        for shade in [0u8, 255] {
            a.push(&vec![shade; (w * h * 3) as usize]).unwrap();
        }
        assert!(a.push(&[0; 5]).is_err(), "a frame of the wrong size is refused");
        assert!(a.finish(2).unwrap());
        let mut opts = gif::DecodeOptions::new();
        opts.set_color_output(gif::ColorOutput::RGBA);
        let mut d = opts.read_info(File::open(&path).unwrap()).unwrap();
        let mut first = Vec::new();
        while let Some(f) = d.read_next_frame().unwrap() {
            assert_eq!((f.width, f.height, f.delay), (8, 4, 20));
            first.push(f.buffer[0]);
        }
        assert_eq!(first, [0, 255], "two frames, black then white");

        let single = dir.join("b.gif");
        let mut b = Animation::new(&single, (w, h), 20).unwrap();
        b.push(&vec![9; (w * h * 3) as usize]).unwrap();
        assert!(!b.finish(2).unwrap());
        assert!(!single.exists() && !dir.join("b.gif.partial").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
