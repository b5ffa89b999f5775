//! Framing: a version byte, a direction byte and a CRC-32 around a postcard message,
//! COBS-stuffed and ended by a zero byte; and the streaming [`FrameDecoder`] that undoes it and counts what went wrong.
//!
//! See the [module documentation](super) for the frame layout and the reasons behind it.

use core::fmt;
use core::marker::PhantomData;

use cobs::{DecodeResult, DecoderState};
use postcard::ser_flavors::{Cobs, Flavor, Slice};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Version of the wire format. Byte 0 of every decoded frame, in every version, forever; any
/// change to a message's layout (a new field, a new or reordered variant) increments it.
///
/// * 1: the first link (hello, ping, poses, parameters, commands, states, events, telemetry).
/// * 2: [`HostMsg::Guide`](super::HostMsg::Guide) (guided writing), appended.
/// * 3: the stored configuration and bring-up: `DeviceInfo::config`, `HostMsg::GetConfig` /
///   `SetConfig`, `DeviceMsg::Config` / `Sensors`, `Command::StreamSensors` / `NudgeMotor`,
///   four `CommandError`s, `Capabilities::STORED_CONFIG`; host frames up to 512 bytes.
/// * 4: `DeviceConfig` carries each motor's winding resistance (`DriveConfig::winding_mohm`)
///   and the motor supply and driver rating (`DeviceConfig::power`), which bound the duty
///   (configuration image format 2).
/// * 5: `LayerState::deposited`, the ink each layer has given to the paper (the brush holds a
///   finite load of ink).
/// * 6: the board's tick limits in the handshake (`DeviceInfo::limits`) and the refusals
///   that name them (`RejectReason::OverTickLimit`, `CommandError::OverTickLimit`); the
///   worst tick's busy time and the overruns in `Telemetry`.
/// * 7: `ConfigState::Migrated`, appended: the stored image was of an older configuration
///   format, read into this one, in force for the kinematics but not for the motors until a
///   `SetConfig` gives what that format lacks.
pub const PROTOCOL_VERSION: u8 = 7;

/// The byte that ends every frame. Never appears inside a COBS-stuffed frame. A sender that
/// (re)opens the link may write one first so the receiver drops any partial frame it holds.
pub const DELIMITER: u8 = 0x00;

/// Byte 1 of a host-to-device frame.
pub const HOST_TO_DEVICE: u8 = b'H';
/// Byte 1 of a device-to-host frame.
pub const DEVICE_TO_HOST: u8 = b'D';
/// Length of the header: version byte and direction byte.
pub const HEADER_LEN: usize = 2;
/// Length of the CRC-32 trailer (little-endian).
pub const CRC_LEN: usize = 4;

/// CRC-32/ISO-HDLC (the zlib / Ethernet CRC: poly 0x04C11DB7 reflected, init and xor-out
/// 0xFFFFFFFF), bit by bit: the byte-wise form's 1 KiB table is flash the Black Pill's image
/// does not have, and the bits cost the link task, not the force loop, a few tens of
/// instructions a byte.
static CRC32: crc::Crc<u32, crc::NoTable> =
    crc::Crc::<u32, crc::NoTable>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32/ISO-HDLC of `bytes`: what the trailer of a frame holds for the bytes before it.
pub fn crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

/// Longest frame on the wire (COBS overhead and delimiter included) whose decoded content
/// (header, message, CRC) is `decoded` bytes long: COBS adds one code byte plus one per
/// 254 bytes of content.
pub const fn max_frame_len(decoded: usize) -> usize {
    decoded + decoded / 254 + 2
}

/// What can go wrong with a frame, sending or receiving.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ProtocolError {
    /// Not a COBS frame (a zero byte where the stuffing says there cannot be one), or shorter
    /// than the header and the CRC.
    Framing,
    /// The CRC-32 does not match: the bytes were damaged on the way.
    Crc,
    /// The decoded content exceeds the receiver's bound (the rest of the frame was skipped up
    /// to its delimiter); when encoding, the message exceeds the bound its receiver accepts.
    Oversized,
    /// Intact frame of our version whose message postcard cannot decode into the expected
    /// type (or which has bytes left over after it). Counted as a decode error.
    Decode,
    /// Intact frame of our version sent in the other direction: the link echoes our own
    /// frames back (a terminal with echo on, a loop-back). Counted as a decode error.
    WrongDirection,
    /// The peer speaks another version of this protocol: from a frame's version byte or a
    /// handshake's `protocol_version` field.
    VersionMismatch { ours: u8, theirs: u8 },
    /// Encoding: the output buffer cannot hold the frame.
    BufferTooSmall,
}

impl fmt::Display for ProtocolError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ProtocolError::Framing => f.write_str("framing error: not a valid COBS frame"),
            ProtocolError::Crc => f.write_str("CRC error: the frame was damaged on the link"),
            ProtocolError::Oversized => f.write_str("frame larger than the receiver accepts"),
            ProtocolError::Decode => f.write_str("intact frame with an undecodable message"),
            ProtocolError::WrongDirection => {
                f.write_str("received a frame meant for the peer: does the link echo?")
            }
            ProtocolError::VersionMismatch { ours, theirs } => write!(
                f,
                "protocol version mismatch: we speak version {ours}, the peer speaks {theirs}; \
                 update the firmware or the host so both match"
            ),
            ProtocolError::BufferTooSmall => f.write_str("output buffer too small for the frame"),
        }
    }
}

impl core::error::Error for ProtocolError {}

/// Checks a peer's protocol version (from its handshake) against ours.
pub fn check_version(theirs: u8) -> Result<(), ProtocolError> {
    if theirs == PROTOCOL_VERSION {
        Ok(())
    } else {
        Err(ProtocolError::VersionMismatch {
            ours: PROTOCOL_VERSION,
            theirs,
        })
    }
}

/// A message type with its own direction on the link and the bound its receiver enforces.
pub trait Message: Serialize + DeserializeOwned {
    /// The direction byte of this type's frames.
    const DIRECTION: u8;
    /// Largest decoded frame content (header + postcard message + CRC) of this type; the
    /// receiving [`FrameDecoder`] is sized with it, and [`Message::encode`] refuses more.
    const MAX_DECODED: usize;
    /// Largest frame of this type on the wire: size transmit buffers with it.
    const MAX_FRAME: usize = max_frame_len(Self::MAX_DECODED);

    /// Writes one complete frame (ending with the delimiter) to the start of `out` and
    /// returns its length. Never panics; `out` of [`Message::MAX_FRAME`] bytes always suffices
    /// for a message within the bound.
    fn encode(&self, out: &mut [u8]) -> Result<usize, ProtocolError> {
        let mut framer = Framer::new(out, Self::MAX_DECODED)?;
        framer.push(&(PROTOCOL_VERSION, Self::DIRECTION, self))?;
        framer.finish()
    }
}

/// Encodes a frame of `M`'s direction and bound whose message is `message`: any value that
/// serializes as an `M` would (a borrowed view of one), for senders that should not build
/// the owned message first ([`super::DeviceMsg::encode_state`]).
pub(crate) fn encode_as<M: Message, T: Serialize + ?Sized>(
    message: &T,
    out: &mut [u8],
) -> Result<usize, ProtocolError> {
    let mut framer = Framer::new(out, M::MAX_DECODED)?;
    framer.push(&(PROTOCOL_VERSION, M::DIRECTION, message))?;
    framer.finish()
}

/// Frames raw `content` (the version and direction bytes, then postcard message bytes):
/// appends the CRC, COBS-stuffs, adds the delimiter. For tests and protocol tools that need
/// frames no well-typed sender would produce; `max_decoded` bounds it like
/// [`Message::MAX_DECODED`].
pub fn encode_raw(
    content: &[u8],
    max_decoded: usize,
    out: &mut [u8],
) -> Result<usize, ProtocolError> {
    let mut framer = Framer::new(out, max_decoded)?;
    framer.extend(content)?;
    framer.finish()
}

/// Serializer back end: feeds every byte postcard produces through the CRC and the COBS
/// stuffing straight into the output buffer, so encoding needs no scratch buffer.
struct Framer<'a> {
    cobs: Cobs<Slice<'a>>,
    digest: crc::Digest<'static, u32, crc::NoTable>,
    len: usize,
    max_content: usize,
    /// Set when the content limit (not the output buffer) stopped the encoding.
    too_large: bool,
}

impl<'a> Framer<'a> {
    fn new(out: &'a mut [u8], max_decoded: usize) -> Result<Self, ProtocolError> {
        Ok(Framer {
            cobs: Cobs::try_new(Slice::new(out)).map_err(|_| ProtocolError::BufferTooSmall)?,
            digest: CRC32.digest(),
            len: 0,
            max_content: max_decoded.saturating_sub(CRC_LEN),
            too_large: false,
        })
    }

    fn extend(&mut self, data: &[u8]) -> Result<(), ProtocolError> {
        let len = self.len.saturating_add(data.len());
        if len > self.max_content {
            self.too_large = true;
            return Err(ProtocolError::Oversized);
        }
        self.len = len;
        self.digest.update(data);
        self.cobs
            .try_extend(data)
            .map_err(|_| ProtocolError::BufferTooSmall)
    }

    fn push<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), ProtocolError> {
        match postcard::serialize_with_flavor::<T, _, ()>(value, &mut *self) {
            Ok(()) => Ok(()),
            Err(_) if self.too_large => Err(ProtocolError::Oversized),
            Err(_) => Err(ProtocolError::BufferTooSmall),
        }
    }

    fn finish(self) -> Result<usize, ProtocolError> {
        let Framer {
            mut cobs, digest, ..
        } = self;
        cobs.try_extend(&digest.finalize().to_le_bytes())
            .and_then(|()| cobs.finalize())
            .map(|frame| frame.len())
            .map_err(|_| ProtocolError::BufferTooSmall)
    }
}

/// postcard's serializer writes through a borrowed [`Framer`] (it consumes its flavour, and
/// the framer must survive to append the CRC).
impl Flavor for &mut Framer<'_> {
    type Output = ();

    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.try_extend(&[data])
    }

    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        self.extend(data)
            .map_err(|_| postcard::Error::SerializeBufferFull)
    }

    fn finalize(self) -> postcard::Result<()> {
        Ok(())
    }
}

/// Counters of a receiving [`FrameDecoder`]: frames decoded and frames dropped, by cause.
/// Saturating (a counter stuck at `u32::MAX` never reads as "no errors").
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct LinkStats {
    /// Frames decoded into a message.
    pub frames_ok: u32,
    /// Not COBS, or too short to hold the header and the CRC.
    pub framing_errors: u32,
    /// Intact COBS, wrong CRC.
    pub crc_errors: u32,
    /// Longer than the decoder's buffer; skipped to the next delimiter.
    pub oversized_frames: u32,
    /// Good CRC and version, but postcard could not decode the message, or it came from the
    /// wrong direction (an echo).
    pub decode_errors: u32,
    /// Good CRC, another protocol version.
    pub version_errors: u32,
}

impl LinkStats {
    /// Frames dropped for any reason.
    pub fn dropped(&self) -> u32 {
        self.framing_errors
            .saturating_add(self.crc_errors)
            .saturating_add(self.oversized_frames)
            .saturating_add(self.decode_errors)
            .saturating_add(self.version_errors)
    }

    fn count(&mut self, e: ProtocolError) -> ProtocolError {
        let c = match e {
            ProtocolError::Framing => &mut self.framing_errors,
            ProtocolError::Crc => &mut self.crc_errors,
            ProtocolError::Oversized => &mut self.oversized_frames,
            ProtocolError::Decode | ProtocolError::WrongDirection => &mut self.decode_errors,
            ProtocolError::VersionMismatch { .. } => &mut self.version_errors,
            // Not a receive error; never produced by the decoder.
            ProtocolError::BufferTooSmall => return e,
        };
        *c = c.saturating_add(1);
        e
    }
}

/// Streaming decoder for messages of type `M`, fed arbitrary chunks of the byte stream.
///
/// `N` is the largest decoded frame content it accepts (use `M::MAX_DECODED`, see the
/// [`DeviceRx`](super::DeviceRx) and [`HostRx`](super::HostRx) aliases); the buffer is
/// `N` bytes inside the decoder, nothing is allocated. COBS is undone byte by byte as the
/// bytes arrive, so a frame costs one pass. Every malformed frame is reported once, as an
/// `Err`, when its delimiter arrives, and counted in [`FrameDecoder::stats`]; the decoder is
/// then ready for the next frame, so it resynchronises at the first zero byte after any
/// garbage. No input makes it panic or stall.
#[derive(Debug)]
pub struct FrameDecoder<M, const N: usize> {
    buf: heapless::Vec<u8, N>,
    cobs: DecoderState,
    /// Skipping the rest of an oversized frame up to its delimiter.
    skipping: bool,
    stats: LinkStats,
    _msg: PhantomData<fn() -> M>,
}

impl<M: Message, const N: usize> Default for FrameDecoder<M, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<M: Message, const N: usize> FrameDecoder<M, N> {
    /// An empty decoder (`const`, so it can live in a `static`).
    pub const fn new() -> Self {
        FrameDecoder {
            buf: heapless::Vec::new(),
            cobs: DecoderState::Idle,
            skipping: false,
            stats: LinkStats {
                frames_ok: 0,
                framing_errors: 0,
                crc_errors: 0,
                oversized_frames: 0,
                decode_errors: 0,
                version_errors: 0,
            },
            _msg: PhantomData,
        }
    }

    /// The counters so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Drops a partial frame (e.g. when the link reconnects). Counters are kept.
    pub fn reset(&mut self) {
        self.buf.clear();
        self.cobs = DecoderState::Idle;
        self.skipping = false;
    }

    /// Takes one byte; returns the outcome when it completed a frame.
    pub fn push(&mut self, byte: u8) -> Option<Result<M, ProtocolError>> {
        if self.skipping {
            if byte != DELIMITER {
                return None;
            }
            self.reset();
            return Some(Err(self.stats.count(ProtocolError::Oversized)));
        }
        match self.cobs.feed(byte) {
            Ok(DecodeResult::NoData) => None,
            Ok(DecodeResult::DataContinue(b)) => {
                if self.buf.push(b).is_err() {
                    self.skipping = true;
                }
                None
            }
            Ok(DecodeResult::DataComplete) => {
                let result = self.decode_frame();
                self.buf.clear();
                Some(match result {
                    Ok(msg) => {
                        self.stats.frames_ok = self.stats.frames_ok.saturating_add(1);
                        Ok(msg)
                    }
                    Err(e) => Err(self.stats.count(e)),
                })
            }
            // The COBS state machine only fails on a zero byte: the frame has ended.
            Err(_) => {
                self.reset();
                Some(Err(self.stats.count(ProtocolError::Framing)))
            }
        }
    }

    /// Feeds a chunk; iterate the result for every frame the chunk completes. The chunk is
    /// consumed as far as the iterator is advanced: drain it (a `for` loop does).
    pub fn feed<'d, 'b>(&'d mut self, bytes: &'b [u8]) -> Feed<'d, 'b, M, N> {
        Feed {
            dec: self,
            rest: bytes,
        }
    }

    /// Checks and decodes the content of a complete frame.
    fn decode_frame(&self) -> Result<M, ProtocolError> {
        let frame = self.buf.as_slice();
        let body_len = frame
            .len()
            .checked_sub(CRC_LEN)
            .ok_or(ProtocolError::Framing)?;
        let (body, trailer) = frame
            .split_at_checked(body_len)
            .ok_or(ProtocolError::Framing)?;
        let (header, message) = body
            .split_first_chunk::<HEADER_LEN>()
            .ok_or(ProtocolError::Framing)?;
        let trailer: [u8; CRC_LEN] = trailer.try_into().map_err(|_| ProtocolError::Framing)?;
        if crc32(body) != u32::from_le_bytes(trailer) {
            return Err(ProtocolError::Crc);
        }
        let [version, direction] = *header;
        check_version(version)?;
        if direction != M::DIRECTION {
            return Err(ProtocolError::WrongDirection);
        }
        match postcard::take_from_bytes::<M>(message) {
            Ok((msg, [])) => Ok(msg),
            _ => Err(ProtocolError::Decode),
        }
    }
}

/// Iterator over the frames a chunk completes; see [`FrameDecoder::feed`].
pub struct Feed<'d, 'b, M, const N: usize> {
    dec: &'d mut FrameDecoder<M, N>,
    rest: &'b [u8],
}

impl<M, const N: usize> Feed<'_, '_, M, N> {
    /// The bytes of the chunk not consumed yet.
    pub fn remaining(&self) -> &[u8] {
        self.rest
    }
}

impl<M: Message, const N: usize> Iterator for Feed<'_, '_, M, N> {
    type Item = Result<M, ProtocolError>;

    fn next(&mut self) -> Option<Self::Item> {
        while let Some((&byte, rest)) = self.rest.split_first() {
            self.rest = rest;
            if let Some(outcome) = self.dec.push(byte) {
                return Some(outcome);
            }
        }
        None
    }
}
