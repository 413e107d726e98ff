//! Units of a positioning dataset when they are not millimetres and micrometres.
//!
//! The columns are `target_mm` and `deviation_um` (`docs/datasets.md`), but a rotary axis is
//! measured in degrees and millidegrees (or arc-seconds). The metadata `# target_unit: deg`
//! and `# deviation_unit: mdeg` say so; every number is then read and computed as given, and
//! only the words change: reports name the file's units instead of mm and µm.

/// Units of the target and deviation columns.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Units {
    /// Unit of `target_mm` ("mm" unless the metadata say otherwise).
    pub target: String,
    /// Unit of `deviation_um` ("µm" unless the metadata say otherwise).
    pub deviation: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            target: "mm".into(),
            deviation: "µm".into(),
        }
    }
}

impl Units {
    /// True for millimetres and micrometres (nothing to relabel).
    pub fn is_default(&self) -> bool {
        *self == Units::default()
    }

    /// `text` with mm and µm replaced by the file's units. A scale in µm/m is relative (ppm)
    /// whatever the unit; per-kelvin coefficients become ppm/K. Only whole words change.
    pub fn relabel(&self, text: &str) -> String {
        if self.is_default() {
            return text.to_string();
        }
        let t = text.replace("µm/(m·K)", "ppm/K").replace("µm/m", "ppm");
        let t = replace_word(&t, "µm", &self.deviation);
        replace_word(&t, "mm", &self.target)
    }

    /// What a report says once about the units, when they are not the default.
    pub fn note(&self) -> Option<String> {
        (!self.is_default()).then(|| {
            format!(
                "targets are in {} and deviations in {} (the file's `target_unit` / \
                 `deviation_unit`): every value below is in those units, and the keys named \
                 `_mm` / `_um` hold them too; scales are relative (ppm)",
                self.target, self.deviation
            )
        })
    }
}

/// A unit name a report can print as it is: 1 to 12 letters, digits or the signs µ ° ' " /
/// · ^ - (no markup, no spaces, nothing a page or a chart would read as code).
pub fn is_plain_unit(s: &str) -> bool {
    let n = s.chars().count();
    (1..=12).contains(&n)
        && s.chars()
            .all(|c| c.is_alphanumeric() || "µ°'\"/·^-".contains(c))
}

/// Replaces `word` in `text` where it is not part of a longer word (letters or digits on
/// neither side; a number before it is fine: "12 mm", "(3.0 µm)", "µm/h").
fn replace_word(text: &str, word: &str, by: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(i) = rest.find(word) {
        let before = rest[..i].chars().next_back();
        let after = rest[i + word.len()..].chars().next();
        let joined = |c: Option<char>| c.is_some_and(|c| c.is_alphabetic() || c == '_');
        out.push_str(&rest[..i]);
        if joined(before) || joined(after) {
            out.push_str(word);
        } else {
            // A right-aligned column heading keeps its width: a longer unit takes the spaces
            // before it (one is always left).
            let longer = by.chars().count().saturating_sub(word.chars().count());
            let spaces = out.chars().rev().take_while(|c| *c == ' ').count();
            if spaces > longer {
                out.truncate(out.len() - longer);
            }
            out.push_str(by);
        }
        rest = &rest[i + word.len()..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotary() -> Units {
        Units {
            target: "deg".into(),
            deviation: "mdeg".into(),
        }
    }

    #[test]
    fn words_change_and_nothing_else() {
        let u = rotary();
        assert_eq!(
            u.relabel("noise 0.30 µm, target 3 (20.000 mm), 1.2 µm/h, 15 µm/m, 11.7 µm/(m·K)"),
            "noise 0.30 mdeg, target 3 (20.000 deg), 1.2 mdeg/h, 15 ppm, 11.7 ppm/K"
        );
        // Inside words and keys: unchanged.
        assert_eq!(
            u.relabel("amplitude_um mmHg summit"),
            "amplitude_um mmHg summit"
        );
        assert_eq!(u.relabel("12mm"), "12deg");
        // Right-aligned headings keep their width.
        assert_eq!(u.relabel("      µm      mm"), "    mdeg     deg");
        assert_eq!(Units::default().relabel("1 µm"), "1 µm");
        assert!(Units::default().note().is_none());
        assert!(u.note().is_some_and(|n| n.contains("mdeg")));
    }

    #[test]
    fn only_plain_unit_names_pass() {
        for ok in ["deg", "mdeg", "arcsec", "µrad", "\"", "°"] {
            assert!(is_plain_unit(ok), "{ok}");
        }
        for bad in ["", "<b>deg</b>", "m deg", "a&b", "abcdefghijklm", "x\u{7}"] {
            assert!(!is_plain_unit(bad), "{bad}");
        }
    }
}
