//! The wire format of `eprop serve` (docs/protocol.md): a hello with magic and version, then
//! fixed-size little-endian messages: 40 bytes from the client, 80 bytes from the server.
//! Version 2 adds an optional stream of the deformed surface: a client that asks for it in its
//! hello gets the surface's topology once, then frames of its nodes' displacements, each an
//! 80-byte header followed by the payload the header sizes.

/// The first 8 bytes of both hellos.
pub const MAGIC: [u8; 8] = *b"EPROPHAP";
/// The newest protocol version this server speaks (it answers every version from 1 up).
pub const VERSION: u32 = 3;
/// Version 1: no stream; its clients get exactly the messages they always got.
pub const VERSION_1: u32 = 1;
/// Version 2: the surface stream; its clients get exactly the messages they always got.
pub const VERSION_2: u32 = 2;
/// Version 3 (the hello as version 2's): an answer reaches up to `LAG_REACH` steps beyond
/// the latest physics step while the physics lags, and says so in its flags.
pub const VERSION_3: u32 = 3;
/// Version 3: how many physics steps beyond the latest one an answer may be extrapolated
/// (versions 1 and 2: one).
pub const LAG_REACH: f64 = 10.0;

/// Version 3: the bits of an answer's flags (bytes 6..8; zero in versions 1 and 2).
pub mod flags {
    /// The physics lags: the values are extrapolated linearly from the last two steps more
    /// than one step beyond the latest (up to `LAG_REACH` steps).
    pub const EXTRAPOLATED: u16 = 1;
    /// The physics lags more than `LAG_REACH` steps: t_e is before the message's time.
    pub const BEHIND: u16 = 2;
}
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
    /// Version 2, streaming: the surface's topology (header + payload), once after the hello.
    pub const TOPOLOGY: u32 = 6;
    /// Version 2, streaming: the surface nodes' displacements of one step (header + payload).
    pub const FRAME: u32 = 7;
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
    /// A non-finite value, a tool position beyond `config::REACH`, or a time not after the
    /// last sample of the same tool or load.
    Sample = 6,
    /// The client sent nothing the run needed within the timeout.
    Timeout = 7,
    /// The run failed on the server.
    Server = 8,
    /// A version-2 hello whose stream request is malformed (or a mesh without a surface).
    Stream = 9,
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

/// What a client asks for in its hello.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Opening {
    /// The protocol version the session speaks (1 or 2).
    pub version: u32,
    /// Version 2: the surface stream asked for, if any.
    pub stream: Option<Stream>,
}

/// A stream of the surface: a frame after an answer whenever a step that is a multiple of
/// `every` is newer than the last frame sent; values of `width` bytes (4: f32, 8: f64).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stream {
    pub every: u32,
    pub width: u32,
}

/// What the version-2 hello's field 12..16 asks for.
pub mod stream {
    pub const NONE: u32 = 0;
    /// The displacements of the outer surface's nodes.
    pub const SURFACE: u32 = 1;
}

/// Checks a client hello; the error is the code and text to send back.
pub fn read_hello(b: &[u8; CLIENT_SIZE]) -> Result<Opening, (Code, String)> {
    if b[..8] != MAGIC {
        return Err((
            Code::NotEprop,
            "not an eprop client: the hello must start with the 8 bytes EPROPHAP".into(),
        ));
    }
    let v = u32_at(b, 8);
    if v == VERSION_1 {
        // version 1 never looked at bytes 12..40
        return Ok(Opening {
            version: v,
            stream: None,
        });
    }
    if v != VERSION_2 && v != VERSION_3 {
        return Err((
            Code::Version,
            format!("protocol version {v} is not supported; this server speaks versions 1, 2 and {VERSION}"),
        ));
    }
    let (what, every, width) = (u32_at(b, 12), u32_at(b, 16), u32_at(b, 20));
    if b[24..].iter().any(|&x| x != 0) {
        return Err((Code::Stream, "hello bytes 24..40 must be zero".into()));
    }
    let stream = match what {
        stream::NONE if every == 0 && width == 0 => None,
        stream::NONE => {
            return Err((
                Code::Stream,
                "no stream asked (bytes 12..16 zero): every and width must be zero".into(),
            ))
        }
        stream::SURFACE if every == 0 => return Err((Code::Stream, "stream every 0 steps: give 1 or more".into())),
        stream::SURFACE if width != 4 && width != 8 => {
            return Err((
                Code::Stream,
                format!("stream value width {width}: give 4 (f32) or 8 (f64)"),
            ))
        }
        stream::SURFACE => Some(Stream { every, width }),
        _ => {
            return Err((
                Code::Stream,
                format!("stream kind {what}: give 0 (none) or 1 (surface)"),
            ))
        }
    };
    Ok(Opening { version: v, stream })
}

pub fn client_hello(version: u32) -> [u8; CLIENT_SIZE] {
    let mut b = [0u8; CLIENT_SIZE];
    b[..8].copy_from_slice(&MAGIC);
    b[8..12].copy_from_slice(&version.to_le_bytes());
    b
}

/// A version-2 hello that asks for the surface stream.
pub fn client_hello_stream(s: Stream) -> [u8; CLIENT_SIZE] {
    let mut b = client_hello(VERSION_2);
    b[12..16].copy_from_slice(&stream::SURFACE.to_le_bytes());
    b[16..20].copy_from_slice(&s.every.to_le_bytes());
    b[20..24].copy_from_slice(&s.width.to_le_bytes());
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
    /// The session's version: the client's (1 or 2).
    pub version: u32,
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
    /// Version 2 with a stream: the surface's nodes and triangles (0 otherwise).
    pub surface_nodes: u32,
    pub surface_triangles: u32,
}

pub fn server_hello(h: &Hello) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&answer::HELLO.to_le_bytes());
    b[4..8].copy_from_slice(&h.version.to_le_bytes());
    b[8..16].copy_from_slice(&MAGIC);
    for (k, v) in [h.tools, h.loads, h.live_tools, h.live_loads].iter().enumerate() {
        b[16 + 4 * k..20 + 4 * k].copy_from_slice(&v.to_le_bytes());
    }
    b[32..40].copy_from_slice(&h.dt.to_le_bytes());
    b[40..48].copy_from_slice(&h.t0.to_le_bytes());
    b[48..56].copy_from_slice(&h.timeout.to_le_bytes());
    b[56..64].copy_from_slice(&h.max_steps.to_le_bytes());
    b[64..68].copy_from_slice(&h.surface_nodes.to_le_bytes());
    b[68..72].copy_from_slice(&h.surface_triangles.to_le_bytes());
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
    /// The header of a topology or frame (version 2, streaming); `bytes` of payload follow.
    Payload(Header),
}

/// The 80-byte header of a topology (kind 6) or a frame (kind 7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    pub kind: u32,
    /// Bytes of each value: 4 (f32) or 8 (f64).
    pub width: u32,
    /// Bytes of the payload that follows the header.
    pub bytes: u64,
    pub nodes: u32,
    /// Topology: the triangles (0 in a frame).
    pub triangles: u32,
    /// Topology: the stream's every (0 in a frame).
    pub every: u32,
    /// Frame: the physics step and its time (0 in a topology).
    pub step: u64,
    pub t_step: f64,
}

/// The outer surface a streaming client gets once: rest coordinates (3 per node, the
/// series' units), the nodes' ids in the global numbering (the series' point order) and
/// triangles as indices into the nodes, wound outward.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Topology {
    pub rest: Vec<f64>,
    pub nodes: Vec<u32>,
    pub triangles: Vec<[u32; 3]>,
}

fn put_values(out: &mut Vec<u8>, v: &[f64], width: u32) {
    if width == 4 {
        out.extend(v.iter().flat_map(|&x| (x as f32).to_le_bytes()));
    } else {
        out.extend(v.iter().flat_map(|&x| x.to_le_bytes()));
    }
}

fn header(kind: u32, width: u32, bytes: usize, nodes: usize) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&kind.to_le_bytes());
    b[4..8].copy_from_slice(&width.to_le_bytes());
    b[8..16].copy_from_slice(&(bytes as u64).to_le_bytes());
    b[16..20].copy_from_slice(&(nodes as u32).to_le_bytes());
    b
}

/// The topology message: header, then rest coordinates (3 n values of `width` bytes), node
/// ids (n u32), triangles (3 m u32).
pub fn topology(t: &Topology, s: Stream) -> Vec<u8> {
    let (n, m, w) = (t.nodes.len(), t.triangles.len(), s.width as usize);
    let bytes = 3 * n * w + 4 * n + 12 * m;
    let mut out = Vec::with_capacity(SERVER_SIZE + bytes);
    let mut h = header(answer::TOPOLOGY, s.width, bytes, n);
    h[20..24].copy_from_slice(&(m as u32).to_le_bytes());
    h[24..28].copy_from_slice(&s.every.to_le_bytes());
    out.extend_from_slice(&h);
    put_values(&mut out, &t.rest, s.width);
    out.extend(t.nodes.iter().flat_map(|g| g.to_le_bytes()));
    out.extend(t.triangles.iter().flatten().flat_map(|g| g.to_le_bytes()));
    out
}

/// A frame message: header, then the displacements (3 per surface node, in the topology's
/// node order) of physics step `step` at time `t_step`.
pub fn frame(step: u64, t_step: f64, u: &[f64], width: u32) -> Vec<u8> {
    let bytes = u.len() * width as usize;
    let mut out = Vec::with_capacity(SERVER_SIZE + bytes);
    let mut h = header(answer::FRAME, width, bytes, u.len() / 3);
    h[32..40].copy_from_slice(&step.to_le_bytes());
    h[40..48].copy_from_slice(&t_step.to_le_bytes());
    out.extend_from_slice(&h);
    put_values(&mut out, u, width);
    out
}

/// Values of `width` bytes as f64 (for clients and tests).
pub fn read_values(b: &[u8], width: u32) -> Vec<f64> {
    if width == 4 {
        b.chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap())))
            .collect()
    } else {
        b.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }
}

/// Decodes a topology's payload (for clients and tests).
pub fn read_topology(h: &Header, b: &[u8]) -> Topology {
    let (n, w) = (h.nodes as usize, h.width as usize);
    let u32s = |b: &[u8]| -> Vec<u32> {
        b.chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let tri = u32s(&b[3 * n * w + 4 * n..]);
    Topology {
        rest: read_values(&b[..3 * n * w], h.width),
        nodes: u32s(&b[3 * n * w..3 * n * w + 4 * n]),
        triangles: tri.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}

/// One answer: the contact force and displacement of a tool or load from physics step
/// `step` (time `t_step`), extrapolated linearly in time to `t`; `flags` (version 3, bytes
/// 6..8 above the 16-bit index) say whether the physics lags (`flags::*`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Answer {
    pub kind: u32,
    pub index: u32,
    pub flags: u16,
    pub step: u64,
    pub t_step: f64,
    pub t: f64,
    pub force: [f64; 3],
    pub displacement: [f64; 3],
}

pub fn answer(a: &Answer) -> [u8; SERVER_SIZE] {
    let mut b = [0u8; SERVER_SIZE];
    b[0..4].copy_from_slice(&a.kind.to_le_bytes());
    b[4..8].copy_from_slice(&(a.index & 0xffff | u32::from(a.flags) << 16).to_le_bytes());
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
            version: u32_at(b, 4),
            tools: u32_at(b, 16),
            loads: u32_at(b, 20),
            live_tools: u32_at(b, 24),
            live_loads: u32_at(b, 28),
            dt: f64_at(b, 32),
            t0: f64_at(b, 40),
            timeout: f64_at(b, 48),
            max_steps: u64::from_le_bytes(b[56..64].try_into().unwrap()),
            surface_nodes: u32_at(b, 64),
            surface_triangles: u32_at(b, 68),
        }),
        answer::TOPOLOGY | answer::FRAME => Reply::Payload(Header {
            kind: k,
            width: u32_at(b, 4),
            bytes: u64::from_le_bytes(b[8..16].try_into().unwrap()),
            nodes: u32_at(b, 16),
            triangles: u32_at(b, 20),
            every: u32_at(b, 24),
            step: u64::from_le_bytes(b[32..40].try_into().unwrap()),
            t_step: f64_at(b, 40),
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
            index: u32_at(b, 4) & 0xffff,
            flags: (u32_at(b, 4) >> 16) as u16,
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
            version: VERSION_1,
            tools: 2,
            loads: 1,
            live_tools: 2,
            live_loads: 0,
            dt: 1e-3,
            t0: 0.0,
            timeout: 10.0,
            max_steps: 1000,
            surface_nodes: 0,
            surface_triangles: 0,
        };
        let b = server_hello(&h);
        assert_eq!(&b[8..16], b"EPROPHAP");
        // version 1's hello: version 1 at 4..8, zeros after the step limit
        assert_eq!(&b[4..8], &1u32.to_le_bytes());
        assert!(b[64..].iter().all(|&x| x == 0));
        assert_eq!(read_reply(&b), Reply::Hello(h));
        let a = Answer {
            kind: answer::TOOL,
            index: 1,
            flags: 0,
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
    fn topology_and_frames_round_trip_at_their_documented_offsets() {
        let t = Topology {
            rest: vec![0.0, 1.0, 2.0, 0.1, 1.1, 2.1, 0.2, 1.2, 2.2],
            nodes: vec![3, 7, 9],
            triangles: vec![[0, 1, 2]],
        };
        for width in [4, 8] {
            let s = Stream { every: 5, width };
            let b = topology(&t, s);
            let h = match read_reply(b[..SERVER_SIZE].try_into().unwrap()) {
                Reply::Payload(h) => h,
                r => panic!("{r:?}"),
            };
            assert_eq!((h.kind, h.width, h.nodes, h.triangles, h.every), (6, width, 3, 1, 5));
            assert_eq!(h.bytes as usize, b.len() - SERVER_SIZE);
            assert_eq!(h.bytes as usize, 9 * width as usize + 12 + 12);
            let back = read_topology(&h, &b[SERVER_SIZE..]);
            assert_eq!((&back.nodes, &back.triangles), (&t.nodes, &t.triangles));
            let want: Vec<f64> = if width == 4 {
                t.rest.iter().map(|&x| f64::from(x as f32)).collect()
            } else {
                t.rest.clone()
            };
            assert_eq!(back.rest, want);
            // the ids start right after the coordinates
            let at = SERVER_SIZE + 9 * width as usize;
            assert_eq!(&b[at..at + 4], &3u32.to_le_bytes());
            let u = [1e-3, -2e-3, 0.5, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0];
            let f = frame(42, 0.042, &u, width);
            let h = match read_reply(f[..SERVER_SIZE].try_into().unwrap()) {
                Reply::Payload(h) => h,
                r => panic!("{r:?}"),
            };
            assert_eq!((h.kind, h.width, h.nodes, h.step, h.t_step), (7, width, 3, 42, 0.042));
            assert_eq!(&f[32..40], &42u64.to_le_bytes());
            assert_eq!(h.bytes as usize, 9 * width as usize);
            let v = read_values(&f[SERVER_SIZE..], width);
            if width == 8 {
                assert_eq!(v, u);
            } else {
                assert!(v.iter().zip(u).all(|(a, b)| *a == f64::from(b as f32)));
            }
        }
    }

    #[test]
    fn stream_requests_are_checked() {
        let ok = Stream { every: 3, width: 4 };
        assert_eq!(
            read_hello(&client_hello_stream(ok)),
            Ok(Opening {
                version: 2,
                stream: Some(ok)
            })
        );
        assert_eq!(
            read_hello(&client_hello(VERSION_2)),
            Ok(Opening {
                version: 2,
                stream: None
            })
        );
        assert_eq!(
            read_hello(&client_hello(VERSION_3)),
            Ok(Opening {
                version: 3,
                stream: None
            })
        );
        // version 1 ignores bytes 12..40, as it always did
        let mut v1 = client_hello(VERSION_1);
        v1[12..40].fill(0xff);
        assert_eq!(
            read_hello(&v1),
            Ok(Opening {
                version: 1,
                stream: None
            })
        );
        let bad = |f: &dyn Fn(&mut [u8; CLIENT_SIZE])| {
            let mut b = client_hello_stream(ok);
            f(&mut b);
            read_hello(&b).unwrap_err().0
        };
        assert_eq!(bad(&|b| b[16..20].fill(0)), Code::Stream); // every 0
        assert_eq!(bad(&|b| b[20] = 2), Code::Stream); // width 2
        assert_eq!(bad(&|b| b[12] = 7), Code::Stream); // stream kind 7
        assert_eq!(bad(&|b| b[39] = 1), Code::Stream); // reserved bytes
        assert_eq!(bad(&|b| b[12] = 0), Code::Stream); // no stream, but every and width
        assert_eq!(bad(&|b| b[8] = 4), Code::Version);
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
