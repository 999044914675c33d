//! Text encodings of the page's data: base64 of little-endian `f32` arrays for bulk
//! positions and values, JSON numbers and strings for the rest, and HTML escaping for
//! text shown in the page.
//!
//! Written here rather than taken from a crate because each is a few lines and the
//! viewer must stay dependency-free.

pub(crate) const ALPHABET: &[u8; 64] =
    b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// Standard base64 (RFC 4648, with `=` padding) of `bytes`, as the browser's `atob`
/// decodes it.
#[must_use]
pub(crate) fn base64(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(base64_len(bytes.len()));
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        // Four 6-bit groups; a short chunk pads the groups it does not reach with `=`.
        for (k, shift) in [18u32, 12, 6, 0].into_iter().enumerate() {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[((n >> shift) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Length of the base64 text of `n` bytes.
#[must_use]
pub(crate) fn base64_len(n: usize) -> usize {
    n.div_ceil(3) * 4
}

/// Base64 of `values` stored as little-endian `f32` (about seven significant digits).
#[must_use]
pub(crate) fn f32_base64(values: impl IntoIterator<Item = f64>) -> String {
    let mut bytes = Vec::new();
    for v in values {
        // The rounding to f32 is the stated precision of the page.
        #[allow(clippy::cast_possible_truncation)]
        bytes.extend_from_slice(&(v as f32).to_le_bytes());
    }
    base64(&bytes)
}

/// A finite number as the shortest JSON decimal that reads back as the same `f32`.
///
/// Callers validate that numbers are finite first; a non-finite value would not be
/// JSON, so it is written as `0` rather than produce a page that cannot load.
#[must_use]
pub(crate) fn json_number(v: f64) -> String {
    #[allow(clippy::cast_possible_truncation)]
    let single = v as f32;
    if single.is_finite() {
        // Debug switches to exponent notation for very large and small magnitudes, so
        // the text stays short; both forms are valid JSON.
        format!("{single:?}")
    } else {
        "0".to_owned()
    }
}

/// `s` as a JSON string literal that is also safe inside an HTML `<script>` element:
/// `<`, `>` and `&` are written as `\u` escapes so no `</script>` can appear.
#[must_use]
pub(crate) fn json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '<' | '>' | '&' | '\u{2028}' | '\u{2029}' => {
                out.push_str(&format!("\\u{:04x}", u32::from(c)));
            }
            c if u32::from(c) < 0x20 => out.push_str(&format!("\\u{:04x}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `s` with the characters that HTML gives meaning to replaced by entities, for text
/// and attribute values.
#[must_use]
pub(crate) fn html_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// `n` with its digits grouped by threes with a space, as the page prints counts
/// ("2 400").
#[must_use]
pub(crate) fn group_thousands(n: usize) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (k, c) in digits.chars().enumerate() {
        if k > 0 && (digits.len() - k).is_multiple_of(3) {
            out.push(' ');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_4648_test_vectors() {
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, encoded) in cases {
            assert_eq!(base64(plain.as_bytes()), encoded, "input {plain:?}");
            assert_eq!(base64_len(plain.len()), encoded.len(), "input {plain:?}");
        }
        // Every byte value, so each of the 64 symbols and the high bits are exercised.
        let all: Vec<u8> = (0..=255).collect();
        let text = base64(&all);
        assert_eq!(decode_base64(&text), all);
    }

    /// A reference decoder for the round trip, written independently of the encoder
    /// (the viewer's tests also read embedded fields with it).
    pub(in crate::viewer) fn decode_base64(text: &str) -> Vec<u8> {
        let value = |c: u8| ALPHABET.iter().position(|&a| a == c).unwrap() as u32;
        let mut out = Vec::new();
        for chunk in text.as_bytes().chunks(4) {
            let pad = chunk.iter().filter(|&&c| c == b'=').count();
            let n = chunk
                .iter()
                .map(|&c| if c == b'=' { 0 } else { value(c) })
                .fold(0u32, |acc, v| (acc << 6) | v);
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            out.extend_from_slice(&bytes[..3 - pad]);
        }
        out
    }

    #[test]
    fn f32_base64_round_trips_to_the_nearest_f32() {
        let values = [0.0, -1.5, 1.0 / 3.0, 1e-30, 12_345.678_9];
        let bytes = decode_base64(&f32_base64(values));
        assert_eq!(bytes.len(), 4 * values.len());
        for (k, v) in values.iter().enumerate() {
            let back = f32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap());
            assert_eq!(back, *v as f32, "value {k}");
        }
    }

    #[test]
    fn json_numbers_read_back_as_the_same_f32() {
        for v in [0.0, -2.0, 0.1, 1e-12, 3.4e30, 123.456] {
            let text = json_number(v);
            let back: f32 = text.parse().unwrap();
            assert_eq!(back, v as f32, "{text}");
        }
        assert_eq!(json_number(f64::NAN), "0");
        assert_eq!(json_number(1e300), "0", "overflows f32");
    }

    #[test]
    fn json_strings_cannot_close_the_script_element() {
        let s = json_string("a\"b\\c</script>\n\u{1}");
        assert_eq!(s, "\"a\\\"b\\\\c\\u003c/script\\u003e\\n\\u0001\"");
        assert!(!s.contains('<'));
    }

    #[test]
    fn html_escape_replaces_markup_characters() {
        assert_eq!(
            html_escape("<b>\"x\" & 'y'</b>"),
            "&lt;b&gt;&quot;x&quot; &amp; &#39;y&#39;&lt;/b&gt;"
        );
    }

    #[test]
    fn thousands_are_grouped_by_threes() {
        let cases = [
            (0, "0"),
            (999, "999"),
            (1000, "1 000"),
            (2400, "2 400"),
            (1_234_567, "1 234 567"),
        ];
        for (n, text) in cases {
            assert_eq!(group_thousands(n), text);
        }
    }
}
