//! The wire format of `eprop serve` (docs/protocol.md): a hello with magic and version, then
//! fixed-size little-endian messages: 40 bytes from the client, 80 bytes from the server.

/// The first 8 bytes of both hellos.
pub const MAGIC: [u8; 8] = *b"EPROPHAP";
pub const VERSION: u32 = 1;
/// Size of every client message (the hello included).
pub const CLIENT_SIZE: usize = 40;
/// Size of every server message.
pub const SERVER_SIZE: usize = 80;
/// At most this many tools and loads can be live (the hello's masks).
pub const MAX_LIVE: usize = 32;

/// Kinds of client messages (after the hello).
pub mod kind {
    pub const POSE: u32 = 2;
    pub const FORCE: u32 = 3;
    pub const BYE: u32 = 4;
}

/// Kinds of server messages.
pub mod answer {
    pub const HELLO: u32 = 1;
    pub const TOOL: u32 = 2;
    pub const LOAD: u32 = 3;
    pub const BYE: u32 = 4;
    /// The run reached its stop condition; the connection closes after this message.
    pub const END: u32 = 5;
    pub const ERROR: u32 = 255;
}

/// Error codes of an `answer::ERROR` message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum Code {
    /// The hello does not start with the magic bytes.
    NotEprop = 1,
    /// The client speaks another version.
    Version = 2,
    /// Another client holds the session.
    Busy = 3,
    /// An unknown message kind.
    Kind = 4,
    /// No live tool or load of that index.
    Index = 5,
    /// A non-finite value, or a time not after the last sample of the same tool or load.
    Sample = 6,
    /// The client sent nothing the run needed within the timeout.
    Timeout = 7,
    /// The run failed on the server.
    Server = 8,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// A client message after the hello.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// Tool `index` is at `position` at time `t`.
    Pose {
        index: u32,
        t: f64,
        position: [f64; 3],
    },
    /// Load `index` is `force` at time `t`.
    Force {
        index: u32,
        t: f64,
        force: [f64; 3],
    },
    Bye,
}

/// Checks a client hello; the error is the code and text to send back.
pub fn read_hello(b: &[u8; CLIENT_SIZE]) -> Result<(), (Code, String)> {
    if b[..8] != MAGIC {
        return Err((
            Code::NotEprop,
            "not an eprop client: the hello must start with the 8 bytes EPROPHAP".into(),
        ));
    }
    let v = u32_at(b, 8);
    if v != VERSION {
        return Err((
            Code::Version,
            format!("protocol version {v} is not supported; this server speaks version {VERSION}"),
        ));
    }
    Ok(())
}

pub fn client_hello(version: u32) -> [u8; CLIENT_SIZE] {
    let mut b = [0u8; CLIENT_SIZE];
    b[..8].copy_from_slice(&MAGIC);
    b[8..12].copy_from_slice(&version.to_le_bytes());
    b
}

/// Decodes a client message (the checks of indices and times need the run, see `serve`).
pub fn read_message(b: &[u8; CLIENT_SIZE]) -> Result<Message, (Code, String)> {
    let k = u32_at(b, 0);
    let index = u32_at(b, 4);
    let t = f64_at(b, 8);
    let v = [f64_at(b, 16), f64_at(b, 24), f64_at(b, 32)];
    if k == kind::BYE {
        return Ok(Message::Bye);
    }
    if k != kind::POSE && k != kind::FORCE {
        return Err((Code::Kind, format!("unknown message kind {k} (2 pose, 3 force, 4 bye)")));
    }
    if !t.is_finite() || v.iter().any(|x| !x.is_finite()) {
        return Err((Code::Sample, "a time or value is not finite".into()));
    }
    Ok(if k == kind::POSE {
        Message::Pose { index, t, position: v }
    } else {
        Message::Force { index, t, force: v }
    })
}

pub fn client_message(kind: u32, index: u32, t: f64, v: [f64; 3]) -> [u8; CLIENT_SIZE] {
    let mut b = [0u8; CLIENT_SIZE];
    b[0..4].copy_from_slice(&kind.to_le_bytes());
    b[4..8].copy_from_slice(&index.to_le_bytes());
    b[8..16].copy_from_slice(&t.to_le_bytes());
    for d in 0..3 {
        b[16 + 8 * d..24 + 8 * d].copy_from_slice(&v[d].to_le_bytes());
    }
    b
}

/// What the server's hello tells the client about the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hello {
    pub tools: u32,
    pub loads: u32,
    /// Bit k set: tool (load) k is live.
    pub live_tools: u32,
    pub live_loads: u32,
    /// The mechanics step and the time of step 0.
    pub dt: f64,
    pub t0: f64,
    /// Seconds the run waits for the client.
    pub timeout: f64,
    /// The step the run stops at, at most.
    pub max_steps: u64,
}

pub fn server_hello(h: &Hello) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&answer::HELLO.to_le_bytes());
    b[4..8].copy_from_slice(&VERSION.to_le_bytes());
    b[8..16].copy_from_slice(&MAGIC);
    for (k, v) in [h.tools, h.loads, h.live_tools, h.live_loads].iter().enumerate() {
        b[16 + 4 * k..20 + 4 * k].copy_from_slice(&v.to_le_bytes());
    }
    b[32..40].copy_from_slice(&h.dt.to_le_bytes());
    b[40..48].copy_from_slice(&h.t0.to_le_bytes());
    b[48..56].copy_from_slice(&h.timeout.to_le_bytes());
    b[56..64].copy_from_slice(&h.max_steps.to_le_bytes());
    b
}

/// A server message as a client reads it.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    Hello(Hello),
    /// An answer (`kind` TOOL, LOAD, BYE or END).
    Answer(Answer),
    Error {
        code: u32,
        message: String,
    },
}

/// One answer: the contact force and displacement of a tool or load from physics step
/// `step` (time `t_step`), extrapolated linearly in time to `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Answer {
    pub kind: u32,
    pub index: u32,
    pub step: u64,
    pub t_step: f64,
    pub t: f64,
    pub force: [f64; 3],
    pub displacement: [f64; 3],
}

pub fn answer(a: &Answer) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&a.kind.to_le_bytes());
    b[4..8].copy_from_slice(&a.index.to_le_bytes());
    b[8..16].copy_from_slice(&a.step.to_le_bytes());
    b[16..24].copy_from_slice(&a.t_step.to_le_bytes());
    b[24..32].copy_from_slice(&a.t.to_le_bytes());
    for d in 0..3 {
        b[32 + 8 * d..40 + 8 * d].copy_from_slice(&a.force[d].to_le_bytes());
        b[56 + 8 * d..64 + 8 * d].copy_from_slice(&a.displacement[d].to_le_bytes());
    }
    b
}

/// An error message: the code and up to 72 bytes of UTF-8 text (cut at a character).
pub fn error(code: Code, text: &str) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&answer::ERROR.to_le_bytes());
    b[4..8].copy_from_slice(&(code as u32).to_le_bytes());
    let mut n = text.len().min(SERVER_SIZE - 8);
    while !text.is_char_boundary(n) {
        n -= 1;
    }
    b[8..8 + n].copy_from_slice(&text.as_bytes()[..n]);
    b
}

/// Decodes a server message (for clients and tests).
pub fn read_reply(b: &[u8; SERVER_SIZE]) -> Reply {
    let k = u32_at(b, 0);
    match k {
        answer::HELLO => Reply::Hello(Hello {
            tools: u32_at(b, 16),
            loads: u32_at(b, 20),
            live_tools: u32_at(b, 24),
            live_loads: u32_at(b, 28),
            dt: f64_at(b, 32),
            t0: f64_at(b, 40),
            timeout: f64_at(b, 48),
            max_steps: u64::from_le_bytes(b[56..64].try_into().unwrap()),
        }),
        answer::ERROR => {
            let text = &b[8..];
            let end = text.iter().position(|&c| c == 0).unwrap_or(text.len());
            Reply::Error {
                code: u32_at(b, 4),
                message: String::from_utf8_lossy(&text[..end]).into_owned(),
            }
        }
        _ => Reply::Answer(Answer {
            kind: k,
            index: u32_at(b, 4),
            step: u64::from_le_bytes(b[8..16].try_into().unwrap()),
            t_step: f64_at(b, 16),
            t: f64_at(b, 24),
            force: [f64_at(b, 32), f64_at(b, 40), f64_at(b, 48)],
            displacement: [f64_at(b, 56), f64_at(b, 64), f64_at(b, 72)],
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip_at_their_documented_offsets() {
        let m = client_message(kind::POSE, 3, 0.25, [1.0, -2.0, 3.5]);
        assert_eq!(&m[0..4], &[2, 0, 0, 0]);
        assert_eq!(&m[8..16], &0.25f64.to_le_bytes());
        assert_eq!(
            read_message(&m),
            Ok(Message::Pose {
                index: 3,
                t: 0.25,
                position: [1.0, -2.0, 3.5]
            })
        );
        assert_eq!(
            read_message(&client_message(kind::FORCE, 0, 1.0, [0.0; 3])),
            Ok(Message::Force {
                index: 0,
                t: 1.0,
                force: [0.0; 3]
            })
        );
        assert_eq!(
            read_message(&client_message(kind::BYE, 0, 0.0, [0.0; 3])),
            Ok(Message::Bye)
        );
        let h = Hello {
            tools: 2,
            loads: 1,
            live_tools: 2,
            live_loads: 0,
            dt: 1e-3,
            t0: 0.0,
            timeout: 10.0,
            max_steps: 1000,
        };
        let b = server_hello(&h);
        assert_eq!(&b[8..16], b"EPROPHAP");
        assert_eq!(read_reply(&b), Reply::Hello(h));
        let a = Answer {
            kind: answer::TOOL,
            index: 1,
            step: 17,
            t_step: 0.017,
            t: 0.0175,
            force: [0.0, 0.0, -1.5],
            displacement: [1e-3, 0.0, -0.2],
        };
        let b = answer(&a);
        assert_eq!(&b[32..40], &0.0f64.to_le_bytes());
        assert_eq!(&b[72..80], &(-0.2f64).to_le_bytes());
        assert_eq!(read_reply(&b), Reply::Answer(a));
    }

    #[test]
    fn bad_messages_have_their_codes() {
        assert!(read_hello(&client_hello(VERSION)).is_ok());
        let mut b = client_hello(VERSION);
        b[0] = b'G';
        assert_eq!(read_hello(&b).unwrap_err().0, Code::NotEprop);
        assert_eq!(read_hello(&client_hello(7)).unwrap_err().0, Code::Version);
        assert_eq!(
            read_message(&client_message(9, 0, 0.0, [0.0; 3])).unwrap_err().0,
            Code::Kind
        );
        assert_eq!(
            read_message(&client_message(kind::POSE, 0, f64::NAN, [0.0; 3]))
                .unwrap_err()
                .0,
            Code::Sample
        );
        assert_eq!(
            read_message(&client_message(kind::FORCE, 0, 0.0, [0.0, f64::INFINITY, 0.0]))
                .unwrap_err()
                .0,
            Code::Sample
        );
        // an error's text is cut to fit, at a character boundary
        let long = "é".repeat(60);
        match read_reply(&error(Code::Busy, &long)) {
            Reply::Error { code, message } => {
                assert_eq!(code, 3);
                assert_eq!(message, "é".repeat(36));
            }
            r => panic!("{r:?}"),
        }
    }
}
