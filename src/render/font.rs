//! A 3x5 pixel font for the few labels of a picture (digits, exponents,
//! units).

use super::Image;

/// Rows of a glyph, top to bottom, three bits each (left bit first).
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b001, 0b001, 0b001],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        '+' => [0b000, 0b010, 0b111, 0b010, 0b000],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        'e' => [0b000, 0b111, 0b111, 0b100, 0b111],
        'P' => [0b111, 0b101, 0b111, 0b100, 0b100],
        'a' => [0b000, 0b011, 0b101, 0b101, 0b011],
        'v' => [0b000, 0b101, 0b101, 0b101, 0b010],
        'o' => [0b000, 0b111, 0b101, 0b101, 0b111],
        'n' => [0b000, 0b110, 0b101, 0b101, 0b101],
        'M' => [0b101, 0b111, 0b111, 0b101, 0b101],
        'i' => [0b010, 0b000, 0b010, 0b010, 0b010],
        's' => [0b000, 0b011, 0b110, 0b001, 0b110],
        _ => [0; 5],
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub(super) fn width(text: &str, scale: u32) -> u32 {
    (4 * text.chars().count() as u32).saturating_sub(1) * scale
}

/// Draws `text` in dark grey with its top left corner at `(x, y)`, each
/// font pixel a `scale x scale` square.
pub(super) fn draw(image: &mut Image, text: &str, x: u32, y: u32, scale: u32) {
    for (i, c) in text.chars().enumerate() {
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..3u32 {
                if bits >> (2 - col) & 1 == 1 {
                    let (px, py) = (x + (4 * i as u32 + col) * scale, y + row as u32 * scale);
                    for dy in 0..scale {
                        for dx in 0..scale {
                            image.set(px + dx, py + dy, [40, 40, 40]);
                        }
                    }
                }
            }
        }
    }
}
