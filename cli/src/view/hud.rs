//! The viewer's on-screen text: a 5×7 bitmap font (the HD44780's glyphs,
//! upper case only), drawn into the picture so that no font crate is needed.

/// Glyph rows, top to bottom, the five low bits of each row its pixels (bit 4 leftmost).
const GLYPHS: [(char, [u8; 7]); 49] = [
    ('0', [0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110]),
    ('1', [0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('2', [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111]),
    ('3', [0b11111, 0b00010, 0b00100, 0b00010, 0b00001, 0b10001, 0b01110]),
    ('4', [0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010]),
    ('5', [0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110]),
    ('6', [0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110]),
    ('7', [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000]),
    ('8', [0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110]),
    ('9', [0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100]),
    ('A', [0b01110, 0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001]),
    ('B', [0b11110, 0b10001, 0b10001, 0b11110, 0b10001, 0b10001, 0b11110]),
    ('C', [0b01110, 0b10001, 0b10000, 0b10000, 0b10000, 0b10001, 0b01110]),
    ('D', [0b11100, 0b10010, 0b10001, 0b10001, 0b10001, 0b10010, 0b11100]),
    ('E', [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b11111]),
    ('F', [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b10000]),
    ('G', [0b01110, 0b10001, 0b10000, 0b10111, 0b10001, 0b10001, 0b01111]),
    ('H', [0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001]),
    ('I', [0b01110, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('J', [0b00111, 0b00010, 0b00010, 0b00010, 0b00010, 0b10010, 0b01100]),
    ('K', [0b10001, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010, 0b10001]),
    ('L', [0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b11111]),
    ('M', [0b10001, 0b11011, 0b10101, 0b10101, 0b10001, 0b10001, 0b10001]),
    ('N', [0b10001, 0b10001, 0b11001, 0b10101, 0b10011, 0b10001, 0b10001]),
    ('O', [0b01110, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110]),
    ('P', [0b11110, 0b10001, 0b10001, 0b11110, 0b10000, 0b10000, 0b10000]),
    ('Q', [0b01110, 0b10001, 0b10001, 0b10001, 0b10101, 0b10010, 0b01101]),
    ('R', [0b11110, 0b10001, 0b10001, 0b11110, 0b10100, 0b10010, 0b10001]),
    ('S', [0b01111, 0b10000, 0b10000, 0b01110, 0b00001, 0b00001, 0b11110]),
    ('T', [0b11111, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100]),
    ('U', [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110]),
    ('V', [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100]),
    ('W', [0b10001, 0b10001, 0b10001, 0b10101, 0b10101, 0b10101, 0b01010]),
    ('X', [0b10001, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b10001]),
    ('Y', [0b10001, 0b10001, 0b10001, 0b01010, 0b00100, 0b00100, 0b00100]),
    ('Z', [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b11111]),
    ('.', [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b01100]),
    (',', [0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b00100, 0b01000]),
    (':', [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b01100, 0b00000]),
    ('/', [0b00000, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b00000]),
    ('-', [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000]),
    ('_', [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b11111]),
    ('(', [0b00010, 0b00100, 0b01000, 0b01000, 0b01000, 0b00100, 0b00010]),
    (')', [0b01000, 0b00100, 0b00010, 0b00010, 0b00010, 0b00100, 0b01000]),
    ('%', [0b11000, 0b11001, 0b00010, 0b00100, 0b01000, 0b10011, 0b00011]),
    ('+', [0b00000, 0b00100, 0b00100, 0b11111, 0b00100, 0b00100, 0b00000]),
    ('=', [0b00000, 0b00000, 0b11111, 0b00000, 0b11111, 0b00000, 0b00000]),
    ('|', [0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100]),
    ('?', [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b00000, 0b00100]),
];

/// Screen pixels per font pixel.
const SCALE: usize = 2;
/// A character cell: 5 + 1 columns, 7 + 3 rows, in font pixels.
const CELL: (usize, usize) = (6, 10);
/// The margin around the text, in screen pixels.
const PAD: usize = 4;

fn glyph(c: char) -> Option<&'static [u8; 7]> {
    let c = c.to_ascii_uppercase();
    if c == ' ' {
        return None;
    }
    GLYPHS.iter().find(|(g, _)| *g == c).or_else(|| GLYPHS.last()).map(|(_, rows)| rows)
}

/// The height in screen pixels of a block of `lines` lines of text.
pub fn height(lines: usize) -> usize {
    lines * CELL.1 * SCALE + 2 * PAD
}

/// Draws `lines` at the top left of an RGBA8 picture of `width` × `height`
/// pixels (`stride` bytes a row): white text on a darkened band as wide as
/// the longest line, so that it reads over any volume. Whatever falls outside
/// the picture is clipped.
pub fn draw(rgba: &mut [u8], (width, height): (usize, usize), stride: usize, lines: &[String]) {
    let cols = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let (w, h) = ((cols * CELL.0 * SCALE + 2 * PAD).min(width), self::height(lines.len()).min(height));
    for y in 0..h {
        for px in rgba[y * stride..].chunks_exact_mut(4).take(w) {
            for v in &mut px[..3] {
                *v /= 3;
            }
        }
    }
    for (row, line) in lines.iter().enumerate() {
        for (col, c) in line.chars().enumerate() {
            let Some(rows) = glyph(c) else { continue };
            for (gy, bits) in rows.iter().enumerate() {
                for gx in 0..5 {
                    if bits & (0b10000 >> gx) == 0 {
                        continue;
                    }
                    let (x0, y0) = (PAD + (col * CELL.0 + gx) * SCALE, PAD + (row * CELL.1 + gy) * SCALE);
                    for y in y0..(y0 + SCALE).min(h) {
                        for x in x0..(x0 + SCALE).min(w) {
                            if let Some(px) = rgba.get_mut(y * stride + 4 * x..y * stride + 4 * x + 3) {
                                px.fill(255);
                            }
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn glyphs_are_distinct_and_five_wide() {
        for (i, (c, rows)) in super::GLYPHS.iter().enumerate() {
            assert!(rows.iter().all(|r| *r < 32), "{c}");
            assert!(super::GLYPHS[..i].iter().all(|(d, r)| d != c && r != rows), "{c} repeats a glyph");
        }
    }

    #[test]
    fn text_is_drawn_clipped_and_on_a_dark_band() {
        let (w, h) = (40, 12);
        let mut rgba = vec![150u8; w * h * 4];
        super::draw(&mut rgba, (w, h), w * 4, &["I1 and much more than fits".into()]);
        // Darkened, white strokes, nothing past the picture (no panic), alpha untouched.
        assert!(rgba.chunks_exact(4).any(|p| p[..3] == [50, 50, 50]));
        assert!(rgba.chunks_exact(4).any(|p| p[..3] == [255, 255, 255]));
        assert!(rgba.chunks_exact(4).all(|p| p[3] == 150));
        // 'I' is a vertical bar at font column 2: screen column PAD + 2 * SCALE, row PAD + 3 * SCALE.
        let at = |x: usize, y: usize| rgba[(y * w + x) * 4];
        assert_eq!(at(4 + 4, 4 + 6), 255);
        assert_eq!(at(4, 4 + 6), 50);
    }
}
