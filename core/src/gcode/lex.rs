//! The words of a G-code line: comments split off, numbers read as RS-274/NGC reads them.

use crate::error::{Error, Place, Result};

/// One word: a letter and its number, as written.
#[derive(Clone, Debug)]
pub(crate) struct Word {
    /// The letter, upper case.
    pub letter: char,
    /// Its number.
    pub value: f64,
    /// The word as written (letter upper case, number as written).
    pub text: String,
}

/// The words of a block's code (comments removed). Numbers follow RS-274/NGC: an optional sign,
/// digits and at most one decimal point, no exponent; spaces may stand between a letter and its
/// number (`G 91`) and inside neither.
pub(crate) fn words(code: &str, place: &Place) -> Result<Vec<Word>> {
    let mut out = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        if !c.is_ascii_alphabetic() {
            let what = match c {
                '#' | '[' | '<' => {
                    "parameters, expressions and named words (#, [ ], < >) are not read: \
                     volver compensates the positions a program states; write the values out"
                }
                _ => "expected a word (a letter and a number)",
            };
            return Err(Error::input(
                place.clone().at_field(c.to_string()),
                format!("{what}, found '{c}'"),
            ));
        }
        let letter = c.to_ascii_uppercase();
        i += 1;
        while i < chars.len() && chars[i].is_whitespace() {
            i += 1;
        }
        let num_start = i;
        if i < chars.len() && matches!(chars[i], '+' | '-') {
            i += 1;
        }
        while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
            i += 1;
        }
        let num: String = chars[num_start..i].iter().collect();
        let digits = num.chars().filter(char::is_ascii_digit).count();
        let points = num.matches('.').count();
        let value: f64 = match num.parse() {
            Ok(v) if digits > 0 && points <= 1 => v,
            _ => {
                return Err(Error::input(
                    place.clone().at_field(letter.to_string()),
                    format!("word '{letter}' needs a number, found \"{num}\""),
                ));
            }
        };
        // `X1e2` is X1 followed by a word E2 to a control: G-code numbers have no exponent.
        if i + 1 < chars.len()
            && matches!(chars[i], 'e' | 'E')
            && (chars[i + 1].is_ascii_digit() || matches!(chars[i + 1], '+' | '-' | '.'))
        {
            let tail: String = chars[i..]
                .iter()
                .take_while(|c| !c.is_whitespace())
                .collect();
            return Err(Error::input(
                place.clone().at_field(letter.to_string()),
                format!(
                    "{letter}{num}{tail} is not a G-code number (G-code has no exponent; a \
                     control reads {letter}{num} and then a word {tail}): write the number out in \
                     full, or put a space before a real E word"
                ),
            ));
        }
        out.push(Word {
            letter,
            value,
            text: format!("{letter}{num}"),
        });
    }
    Ok(out)
}

/// A line split into its code and its comments (as written, each with its delimiters), or an
/// error for an unclosed comment.
pub(crate) fn split_comments(line: &str, place: &Place) -> Result<(String, Vec<String>)> {
    let mut code = String::new();
    let mut comments = Vec::new();
    let mut depth = 0;
    let mut current = String::new();
    for (i, c) in line.char_indices() {
        match c {
            '(' if depth > 0 => {
                return Err(Error::input(
                    place.clone(),
                    "a comment inside a comment: RS274NGC controls refuse nested comments",
                ));
            }
            '(' => {
                depth += 1;
                current.push(c);
            }
            ')' if depth > 0 => {
                depth -= 1;
                current.push(c);
                if depth == 0 {
                    comments.push(std::mem::take(&mut current));
                }
            }
            ';' if depth == 0 => {
                comments.push(line[i..].to_string());
                break;
            }
            _ if depth == 0 => code.push(c),
            _ => current.push(c),
        }
    }
    if depth > 0 {
        return Err(Error::input(
            place.clone(),
            "a comment '(' is not closed on its line",
        ));
    }
    Ok((code, comments))
}

/// The lines of a program, whatever their endings (LF, CR LF or CR alone).
pub(crate) fn program_lines(text: &str) -> Vec<&str> {
    let mut lines = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find(['\n', '\r']) {
        lines.push(&rest[..i]);
        let skip = if rest[i..].starts_with("\r\n") { 2 } else { 1 };
        rest = &rest[i + skip..];
    }
    if !rest.is_empty() {
        lines.push(rest);
    }
    lines
}
