//! Video frames: the env's RGB picture with a caption panel below it (task, trial, the
//! instruction's words as they are given, the trials' outcomes), written as an animated GIF
//! and, for a poster, a PNG.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::font::{FAMILY, ensure_registered};

/// Height of the caption panel below the picture, in pixels.
pub const CAPTION_HEIGHT: u32 = 80;
/// Smallest canvas width, so that captions stay readable under small pictures.
pub const MIN_WIDTH: u32 = 256;
const FONT_PX: f64 = 13.0;
const LINE_PX: i32 = 16;

/// What the caption says.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Caption {
    /// e.g. "reach-v3" or "north".
    pub task: String,
    /// 0-based trial the frame belongs to, and the number of trials.
    pub trial: usize,
    pub trials: usize,
    /// The words given so far in an instruction phase, or the whole sentence in a trial.
    pub words: Vec<String>,
    /// True while the instruction is being given (the words then show in bold blue).
    pub instructing: bool,
    /// Outcomes of the trials that ended (true = success), shown as ✓ / ✗.
    pub outcomes: Vec<bool>,
}

/// One RGB canvas: picture on top, caption below.
#[derive(Debug, Clone)]
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    /// Row-major RGB, `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

impl Canvas {
    /// Composes `picture` (`pw` x `ph` RGB, centred) and `caption`.
    pub fn compose(picture: &[u8], pw: u32, ph: u32, caption: &Caption) -> anyhow::Result<Self> {
        ensure_registered();
        anyhow::ensure!(
            picture.len() == (pw * ph * 3) as usize,
            "a {pw} x {ph} picture needs {} bytes, got {}",
            pw * ph * 3,
            picture.len()
        );
        let width = pw.max(MIN_WIDTH);
        let height = ph + CAPTION_HEIGHT;
        let mut rgb = vec![255u8; (width * height * 3) as usize];
        let left = ((width - pw) / 2) as usize;
        for y in 0..ph as usize {
            let src = &picture[y * pw as usize * 3..(y + 1) * pw as usize * 3];
            let at = (y * width as usize + left) * 3;
            rgb[at..at + src.len()].copy_from_slice(src);
        }
        draw_caption(&mut rgb, width, height, ph, caption)?;
        Ok(Self { width, height, rgb })
    }

    /// Writes the canvas as a PNG file.
    pub fn save_png(&self, path: &Path) -> anyhow::Result<()> {
        let mut backend = BitMapBackend::new(path, (self.width, self.height));
        backend
            .blit_bitmap((0, 0), (self.width, self.height), &self.rgb)
            .map_err(|e| anyhow::anyhow!("drawing {}: {e:?}", path.display()))?;
        backend
            .present()
            .map_err(|e| anyhow::anyhow!("writing {}: {e:?}", path.display()))
    }
}

/// Splits `words` into lines of at most `max_chars` characters.
pub fn wrap(words: &[String], max_chars: usize) -> Vec<String> {
    let mut lines: Vec<String> = vec![];
    let mut line = String::new();
    for w in words {
        if !line.is_empty() && line.chars().count() + 1 + w.chars().count() > max_chars {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(w);
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

fn draw_caption(
    rgb: &mut [u8],
    width: u32,
    height: u32,
    top: u32,
    c: &Caption,
) -> anyhow::Result<()> {
    let backend = BitMapBackend::with_buffer(rgb, (width, height));
    let root = backend.into_drawing_area();
    let fail = |e: DrawingAreaErrorKind<_>| anyhow::anyhow!("drawing a caption: {e:?}");
    let x = 6;
    let mut y = top as i32 + 4;
    let bold = (FAMILY, FONT_PX, FontStyle::Bold).into_font();
    let plain = (FAMILY, FONT_PX).into_font();
    root.draw(&Text::new(
        format!(
            "{}   trial {}/{}",
            c.task,
            c.trial + 1,
            c.trials.max(c.trial + 1)
        ),
        (x, y),
        bold.clone().color(&BLACK),
    ))
    .map_err(fail)?;
    y += LINE_PX + 2;
    // About 7 px per character at 13 px.
    let max_chars = ((width as i32 - 2 * x) / 7).max(10) as usize;
    let lines = wrap(&c.words, max_chars);
    let style = if c.instructing {
        bold.color(&RGBColor(20, 70, 190))
    } else {
        plain.clone().color(&RGBColor(90, 90, 90))
    };
    // Keep the newest words in view when a long sentence needs more than two lines.
    for line in lines.iter().skip(lines.len().saturating_sub(2)) {
        root.draw(&Text::new(line.clone(), (x, y), style.clone()))
            .map_err(fail)?;
        y += LINE_PX;
    }
    let mut ox = x;
    let oy = top as i32 + CAPTION_HEIGHT as i32 - LINE_PX - 2;
    for (i, ok) in c.outcomes.iter().enumerate() {
        let (text, colour) = if *ok {
            (format!("trial {} \u{2713}", i + 1), RGBColor(20, 140, 40))
        } else {
            (format!("trial {} \u{2717}", i + 1), RGBColor(200, 30, 30))
        };
        let n = text.chars().count() as i32;
        root.draw(&Text::new(text, (ox, oy), plain.clone().color(&colour)))
            .map_err(fail)?;
        ox += n * 8 + 12;
    }
    root.present().map_err(fail)?;
    Ok(())
}

/// An animated GIF being written, one canvas per frame.
pub struct GifWriter {
    encoder: gif::Encoder<BufWriter<File>>,
    width: u16,
    height: u16,
    frames: usize,
}

impl GifWriter {
    pub fn create(path: &Path, width: u32, height: u32) -> anyhow::Result<Self> {
        let file =
            File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        let (w, h) = (u16::try_from(width)?, u16::try_from(height)?);
        let mut encoder = gif::Encoder::new(BufWriter::new(file), w, h, &[])?;
        encoder.set_repeat(gif::Repeat::Infinite)?;
        Ok(Self {
            encoder,
            width: w,
            height: h,
            frames: 0,
        })
    }

    /// Adds a frame shown for `delay_ms` milliseconds.
    pub fn push(&mut self, canvas: &Canvas, delay_ms: u32) -> anyhow::Result<()> {
        anyhow::ensure!(
            canvas.width == u32::from(self.width) && canvas.height == u32::from(self.height),
            "frame size changed"
        );
        // Speed 10 of 30: good colours at a few milliseconds per small frame.
        let mut frame = gif::Frame::from_rgb_speed(self.width, self.height, &canvas.rgb, 10);
        frame.delay = u16::try_from((delay_ms / 10).max(2)).unwrap_or(u16::MAX);
        self.encoder.write_frame(&frame)?;
        self.frames += 1;
        Ok(())
    }

    pub fn frames(&self) -> usize {
        self.frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_wrap_without_losing_any() {
        let words: Vec<String> = "pick up the puck and place it at the goal"
            .split(' ')
            .map(str::to_owned)
            .collect();
        let lines = wrap(&words, 16);
        assert!(lines.iter().all(|l| l.chars().count() <= 16));
        assert_eq!(lines.join(" "), words.join(" "));
        assert!(wrap(&[], 10).is_empty());
    }

    #[test]
    fn a_canvas_has_the_picture_on_top_and_a_caption() {
        let picture = vec![10u8; 64 * 48 * 3];
        let caption = Caption {
            task: "north".into(),
            trial: 1,
            trials: 3,
            words: vec!["go".into(), "north".into()],
            instructing: true,
            outcomes: vec![false],
        };
        let c = Canvas::compose(&picture, 64, 48, &caption).unwrap();
        assert_eq!((c.width, c.height), (MIN_WIDTH, 48 + CAPTION_HEIGHT));
        let px = |x: u32, y: u32| &c.rgb[((y * c.width + x) * 3) as usize..][..3];
        assert_eq!(px(MIN_WIDTH / 2, 10), [10, 10, 10]);
        assert_eq!(
            px(0, 10),
            [255, 255, 255],
            "margins beside a narrow picture are white"
        );
        let caption_ink = (48..48 + CAPTION_HEIGHT)
            .flat_map(|y| (0..c.width).map(move |x| (x, y)))
            .filter(|&(x, y)| px(x, y) != [255, 255, 255])
            .count();
        assert!(
            caption_ink > 100,
            "the caption has text ({caption_ink} pixels)"
        );
    }
}
