//! Zaber ASCII protocol: `/[device] [axis] [id] command args[:CS]` + LF to the device,
//! `@DD A [id] FL STATUS WW data[:CS]` + CRLF back (`#` info lines, `!` alerts).
//!
//! The checksum is the LRC of the bytes after `/` or `@` up to `:`: the two's complement of
//! their sum, as two upper-case hex digits (`/1:CF`, `/1 tools echo:BF`).

use core::fmt::Write;

/// Longest command line this codec writes, bytes.
pub const MAX_COMMAND: usize = 96;

/// A command line, ready to send.
pub type CommandLine = heapless::String<MAX_COMMAND>;

/// LRC checksum of `body`: `(-(sum of bytes)) & 0xFF`.
pub fn checksum(body: &[u8]) -> u8 {
    body.iter()
        .fold(0u8, |s, &b| s.wrapping_add(b))
        .wrapping_neg()
}

/// Writes `/device axis [id] command:CS\n`; `None` if it does not fit [`MAX_COMMAND`].
pub fn command(device: u8, axis: u8, id: Option<u8>, text: &str) -> Option<CommandLine> {
    let mut body: heapless::String<MAX_COMMAND> = heapless::String::new();
    write!(body, "{device} {axis}").ok()?;
    if let Some(id) = id {
        write!(body, " {id}").ok()?;
    }
    if !text.is_empty() {
        write!(body, " {text}").ok()?;
    }
    let cs = checksum(body.as_bytes());
    let mut line = CommandLine::new();
    writeln!(line, "/{body}:{cs:02X}").ok()?;
    Some(line)
}

/// Why a line is not a valid message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError {
    /// Nothing but whitespace.
    Empty,
    /// The checksum does not match the line.
    Checksum,
    /// Not a Zaber message.
    Malformed,
}

/// A reply to a command (`@` line).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply<'a> {
    /// Device address.
    pub device: u8,
    /// Axis (0: the device).
    pub axis: u8,
    /// Message id, if the command had one.
    pub id: Option<u8>,
    /// `OK` (true) or `RJ` (false).
    pub accepted: bool,
    /// `BUSY` (true) or `IDLE` (false).
    pub busy: bool,
    /// Highest-priority warning flag, `--` for none.
    pub warning: [u8; 2],
    /// The data field (a number, or a reason such as `BADCOMMAND`).
    pub data: &'a str,
}

impl Reply<'_> {
    /// Whether the warning flag is a fault (`F*`).
    pub fn fault(&self) -> bool {
        self.warning[0] == b'F'
    }

    /// The warning flag as text.
    pub fn warning_str(&self) -> &str {
        core::str::from_utf8(&self.warning).unwrap_or("??")
    }
}

/// A message from the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// `@...`: the reply to a command.
    Reply(Reply<'a>),
    /// `#...`: an info line (e.g. help text); the text after the address.
    Info(&'a str),
    /// `!...`: an alert (unsolicited); the text after the address.
    Alert(&'a str),
}

/// Parses one line (with or without its CR/LF), checking the checksum when present.
pub fn parse(line: &str) -> Result<Message<'_>, ParseError> {
    let line = line.trim_matches(|c| c == '\r' || c == '\n' || c == ' ');
    if line.is_empty() {
        return Err(ParseError::Empty);
    }
    // The kind is one ASCII character; anything else (e.g. a multi-byte character from
    // line noise) is not a Zaber message, and must not be split inside a character.
    let (kind, rest) = match line.as_bytes()[0] {
        b'@' | b'#' | b'!' => line.split_at(1),
        _ => return Err(ParseError::Malformed),
    };
    let body = strip_checksum(rest)?;
    match kind {
        "@" => parse_reply(body).map(Message::Reply),
        "#" => Ok(Message::Info(body)),
        "!" => Ok(Message::Alert(body)),
        _ => Err(ParseError::Malformed),
    }
}

/// The body of a line without its `:CS` checksum, checked when present.
fn strip_checksum(rest: &str) -> Result<&str, ParseError> {
    match rest.rfind(':') {
        Some(i) => {
            let (body, cs) = (&rest[..i], &rest[i + 1..]);
            let want = u8::from_str_radix(cs, 16).map_err(|_| ParseError::Malformed)?;
            if cs.len() != 2 || checksum(body.as_bytes()) != want {
                return Err(ParseError::Checksum);
            }
            Ok(body)
        }
        None => Ok(rest),
    }
}

fn parse_reply(body: &str) -> Result<Reply<'_>, ParseError> {
    // Fields up to the warning flag, then the data: the rest of the line.
    let mut rest = body;
    let mut next = || -> Result<&str, ParseError> {
        let r = rest.trim_start_matches(' ');
        let end = r.find(' ').unwrap_or(r.len());
        let (field, tail) = r.split_at(end);
        rest = tail;
        if field.is_empty() {
            Err(ParseError::Malformed)
        } else {
            Ok(field)
        }
    };
    let device = next()?.parse().map_err(|_| ParseError::Malformed)?;
    let axis = next()?.parse().map_err(|_| ParseError::Malformed)?;
    let third = next()?;
    let (id, flag) = match third {
        "OK" | "RJ" => (None, third),
        id => (
            Some(id.parse().map_err(|_| ParseError::Malformed)?),
            next()?,
        ),
    };
    let accepted = match flag {
        "OK" => true,
        "RJ" => false,
        _ => return Err(ParseError::Malformed),
    };
    let busy = match next()? {
        "BUSY" => true,
        "IDLE" => false,
        _ => return Err(ParseError::Malformed),
    };
    let warning = match next()?.as_bytes() {
        [a, b] => [*a, *b],
        _ => return Err(ParseError::Malformed),
    };
    let data = rest.trim_start_matches(' ');
    Ok(Reply {
        device,
        axis,
        id,
        accepted,
        busy,
        warning,
        data,
    })
}

/// Writes a reply line `@DD A [id] FL STATUS WW data:CS\r\n` (for the firmware simulator).
pub fn reply_line(
    device: u8,
    axis: u8,
    id: Option<u8>,
    accepted: bool,
    busy: bool,
    warning: &str,
    data: &str,
) -> Option<heapless::String<MAX_COMMAND>> {
    let mut body: heapless::String<MAX_COMMAND> = heapless::String::new();
    write!(body, "{device:02} {axis}").ok()?;
    if let Some(id) = id {
        write!(body, " {id}").ok()?;
    }
    let fl = if accepted { "OK" } else { "RJ" };
    let st = if busy { "BUSY" } else { "IDLE" };
    write!(body, " {fl} {st} {warning} {data}").ok()?;
    let cs = checksum(body.as_bytes());
    let mut line = heapless::String::new();
    write!(line, "@{body}:{cs:02X}\r\n").ok()?;
    Some(line)
}

/// A parsed command (`/device axis [id] text[:CS]`), for the firmware simulator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Command<'a> {
    /// Device address (0: all).
    pub device: u8,
    /// Axis (0: the device).
    pub axis: u8,
    /// Message id.
    pub id: Option<u8>,
    /// The command and its arguments.
    pub text: &'a str,
}

/// Parses a command line, checking the checksum when present.
pub fn parse_command(line: &str) -> Result<Command<'_>, ParseError> {
    let line = line.trim_matches(|c| c == '\r' || c == '\n' || c == ' ');
    let rest = line.strip_prefix('/').ok_or(ParseError::Malformed)?;
    let body = strip_checksum(rest)?;
    // Up to three leading numbers (device, axis, id), then the command text.
    let mut numbers = [None::<u8>; 3];
    let mut rest = body.trim_start_matches(' ');
    for slot in numbers.iter_mut() {
        let end = rest.find(' ').unwrap_or(rest.len());
        match rest[..end].parse::<u8>() {
            Ok(n) if end > 0 => {
                *slot = Some(n);
                rest = rest[end..].trim_start_matches(' ');
            }
            _ => break,
        }
    }
    let [device, axis, id] = numbers;
    let (device, axis, text) = (device.unwrap_or(0), axis.unwrap_or(0), rest.trim_end());
    Ok(Command {
        device,
        axis,
        id,
        text,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Found by `fuzz zaber`: a line starting with a multi-byte character panicked
    /// (`split_at(1)` inside the character) instead of being refused.
    #[test]
    fn fuzz_multibyte_first_character_is_malformed_not_a_panic() {
        assert_eq!(parse("é01 0 OK IDLE -- 0"), Err(ParseError::Malformed));
        assert_eq!(parse("٠"), Err(ParseError::Malformed));
        assert_eq!(parse_command("é"), Err(ParseError::Malformed));
    }

    #[test]
    fn checksum_matches_the_manual_vectors() {
        assert_eq!(checksum(b"1"), 0xCF);
        assert_eq!(checksum(b"1 tools echo"), 0xBF);
        assert_eq!(parse_command("/1:CF").map(|c| c.device), Ok(1));
        assert_eq!(
            parse_command("/1 tools echo:BF").map(|c| c.text),
            Ok("tools echo")
        );
        assert_eq!(parse_command("/1 tools echo:BE"), Err(ParseError::Checksum));
    }

    #[test]
    fn commands_carry_id_and_checksum() {
        let line = command(1, 1, Some(7), "move abs 42667").expect("fits");
        let cmd = parse_command(&line).expect("parses back");
        assert_eq!((cmd.device, cmd.axis, cmd.id), (1, 1, Some(7)));
        assert_eq!(cmd.text, "move abs 42667");
        assert!(line.ends_with('\n'));
        assert_eq!(
            parse_command("/1 1 get pos"),
            Ok(Command {
                device: 1,
                axis: 1,
                id: None,
                text: "get pos"
            })
        );
    }

    #[test]
    fn replies_parse_with_and_without_id() {
        let Ok(Message::Reply(r)) = parse("@01 1 OK IDLE -- 42667\r\n") else {
            panic!("reply")
        };
        assert_eq!((r.device, r.axis, r.id, r.data), (1, 1, None, "42667"));
        assert!(r.accepted && !r.busy && !r.fault());
        let Ok(Message::Reply(r)) = parse("@01 1 RJ IDLE -- BADCOMMAND") else {
            panic!("reply")
        };
        assert!(!r.accepted);
        assert_eq!(r.data, "BADCOMMAND");
        let line = reply_line(1, 1, Some(12), true, true, "WR", "0").expect("fits");
        let Ok(Message::Reply(r)) = parse(&line) else {
            panic!("reply")
        };
        assert_eq!((r.id, r.busy, r.warning_str()), (Some(12), true, "WR"));
        let line = reply_line(1, 1, None, true, false, "FS", "0").expect("fits");
        let Ok(Message::Reply(r)) = parse(&line) else {
            panic!("reply")
        };
        assert!(r.fault());
    }

    #[test]
    fn bad_lines_are_errors_not_panics() {
        assert_eq!(parse(""), Err(ParseError::Empty));
        assert_eq!(parse("@01 1 OK IDLE -- 0:00"), Err(ParseError::Checksum));
        assert_eq!(parse("@01 1 MAYBE IDLE -- 0"), Err(ParseError::Malformed));
        assert_eq!(parse("xyz"), Err(ParseError::Malformed));
        assert_eq!(parse("@"), Err(ParseError::Malformed));
        assert_eq!(parse("@01 1 OK IDLE -- 0:ZZ"), Err(ParseError::Malformed));
        assert!(matches!(parse("#01 1 info"), Ok(Message::Info(_))));
        assert!(matches!(parse("!01 1 IDLE FS"), Ok(Message::Alert(_))));
    }
}
