//! The scene's text, for errors that point at their place (`file:line:col`), and the
//! checks of single values that report through it. Apart from `validate` so that the
//! parts it calls (keyframes) can use it without importing their caller.

use std::ops::Range;

use glam::Vec3;

use crate::model::Location;
use crate::SceneError;

pub(crate) type R<T> = Result<T, SceneError>;

/// Where in the text an error points: 1-based line and column of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// The scene's text, for locating errors.
pub(crate) struct Ctx<'a> {
    pub(crate) file: &'a str,
    pub(crate) text: &'a str,
}

impl Ctx<'_> {
    pub(crate) fn at(&self, span: &Range<usize>) -> Location {
        let (line, column) = line_column(self.text, span.start);
        Location { line, column }
    }

    pub(crate) fn err(&self, span: &Range<usize>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_column(self.text, span.start);
        SceneError { file: self.file.to_string(), line, column, message: message.into() }
    }

    pub(crate) fn finite(&self, span: &Range<usize>, what: &str, v: Vec3) -> R<Vec3> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(span, format!("{what} must be finite numbers, got {v}")))
        }
    }

    pub(crate) fn colour(&self, span: &Range<usize>, what: &str, c: Vec3) -> R<Vec3> {
        let v = self.finite(span, what, c)?;
        if v.min_element() < 0.0 {
            return Err(self.err(span, format!("{what} must not be negative, got {v}")));
        }
        Ok(v)
    }

    pub(crate) fn number(&self, span: &Range<usize>, what: &str, v: f32, ok: Range<f32>) -> R<f32> {
        if v.is_finite() && v >= ok.start && v <= ok.end {
            Ok(v)
        } else {
            Err(self.err(span, format!("{what} must be in [{}, {}], got {v}", ok.start, ok.end)))
        }
    }
}
