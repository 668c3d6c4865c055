//! A file's element lengths checked against its size before it is parsed.
//!
//! dicom-object allocates (and zero-fills) each value at the length its header
//! declares before reading it, so one corrupt length (0xFFFFFFF0 in a 12 KB
//! file) or a transfer syntax that does not match the data (value bytes read as
//! lengths) costs gigabytes before the read fails. [`scan_layout`] walks the
//! element headers, skipping the values, and refuses any declared length longer
//! than what is left of the file, so memory stays bounded by the file's size.

use dicom_core::Tag;
use std::io::{BufReader, Read, Seek, SeekFrom};

/// Implicit VR Little Endian.
const IMPLICIT_LE: &str = "1.2.840.10008.1.2";
/// Explicit VR Big Endian (retired).
const EXPLICIT_BE: &str = "1.2.840.10008.1.2.2";
/// Deflated Explicit VR Little Endian: the data set is compressed, its
/// lengths are not bounded by the file's size.
const DEFLATED: [&str; 2] = ["1.2.840.10008.1.2.1.99", "1.2.840.10008.1.2.8.1"];

const UNDEFINED: u32 = 0xFFFF_FFFF;
const PIXEL_DATA: Tag = Tag(0x7FE0, 0x0010);

/// Walks the file meta group (explicit VR little endian, group 0002) and
/// returns its TransferSyntaxUID (empty if absent), leaving `w` at the first
/// element of the data set; `None` when the stream cannot be rewound there.
fn read_meta_group<R: Read + Seek>(w: &mut Walker<R>) -> Result<Option<String>, LengthError> {
    let mut ts = String::new();
    loop {
        let start = w.pos;
        let Some((tag, _, len)) = w.header(Syntax::ExplicitLe) else {
            break;
        };
        if tag.group() != 0x0002 {
            if w.r.seek(SeekFrom::Start(start)).is_err() {
                return Ok(None);
            }
            w.pos = start;
            break;
        }
        w.check(tag, len, false, "1.2.840.10008.1.2.1 (file meta group)")?;
        if tag == Tag(0x0002, 0x0010) && len <= 64 {
            let mut b = vec![0u8; len as usize];
            if w.r.read_exact(&mut b).is_err() {
                break;
            }
            w.pos += len as u64;
            ts = String::from_utf8_lossy(&b)
                .trim_end_matches(['\0', ' '])
                .to_string();
        } else if w.skip(len).is_err() {
            break;
        }
    }
    Ok(Some(ts))
}

/// Whether `head`, a file's first bytes, starts like a DICOM data set written
/// without the Part 10 header (no preamble, no "DICM", no file meta group), as
/// older archives and some PACS exports do: an implicit VR little endian
/// element of group 0008 (the first group of every image object) whose
/// declared length fits the file. Such files are read as implicit VR little
/// endian, the only syntax the standard allows without a meta group.
pub fn looks_like_bare_dataset(head: &[u8], file_len: u64) -> bool {
    if head.len() < 8 {
        return false;
    }
    let group = u16::from_le_bytes([head[0], head[1]]);
    let element = u16::from_le_bytes([head[2], head[3]]);
    let len = u32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    // Explicit VR would put two upper-case letters where the length starts.
    let explicit = head[4].is_ascii_uppercase() && head[5].is_ascii_uppercase();
    group == 0x0008 && element < 0x0100 && !explicit && u64::from(len) + 8 <= file_len
}

/// Reads as many bytes as `r` has, up to `buf`'s length.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> usize {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) | Err(_) => break,
            Ok(k) => n += k,
        }
    }
    n
}

/// What [`scan_layout`] learned about a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Layout {
    /// The file's size in bytes.
    pub file_len: u64,
    /// TransferSyntaxUID from the file meta group, without padding.
    pub transfer_syntax: String,
    /// The top-level PixelData element's declared length: `Some(None)` for an
    /// undefined length (encapsulated), `None` when the element is absent or
    /// the data set could not be walked (deflated).
    pub pixel_data_len: Option<Option<u32>>,
}

/// A declared length longer than the rest of the file, or one that does not
/// fit its element's VR.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LengthError {
    /// The element (an item tag for a fragment or item).
    pub tag: Tag,
    /// Whether it lies within the top-level PixelData (a fragment).
    pub in_pixel_data: bool,
    /// The declared length, bytes.
    pub len: u32,
    /// Where its value would start, bytes from the start of the file.
    pub offset: u64,
    /// How many bytes follow in the file.
    pub remaining: u64,
    /// The transfer syntax the data set was read with.
    pub transfer_syntax: String,
    /// When set, the length is not a whole number of values of this VR
    /// (its name and value size in bytes), not beyond the file.
    pub misfit_vr: Option<(String, u32)>,
}

impl std::fmt::Display for LengthError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = if self.in_pixel_data && self.tag != PIXEL_DATA {
            "a pixel data fragment".to_string()
        } else {
            tag_name(self.tag)
        };
        if let Some((vr, size)) = &self.misfit_vr {
            return write!(
                f,
                "{what} is {vr} with {} bytes at byte {}, not a whole number of its {size}-byte values (a corrupt header)",
                self.len, self.offset
            );
        }
        write!(
            f,
            "{what} declares {} bytes at byte {}, but only {} bytes follow in the file \
             (a corrupt header, a truncated file, or a transfer syntax {} that does not match the data)",
            self.len, self.offset, self.remaining, self.transfer_syntax
        )
    }
}

/// "PixelData (7FE0,0010)", or the tag alone when the dictionary does not know it.
pub fn tag_name(tag: Tag) -> String {
    use dicom_core::dictionary::DataDictionary;
    match dicom_dictionary_std::StandardDataDictionary.by_tag(tag) {
        Some(entry) => format!("{} {tag}", entry.alias),
        None => tag.to_string(),
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Syntax {
    ExplicitLe,
    ExplicitBe,
    ImplicitLe,
}

/// VRs with a 2-byte reserved field and a 4-byte length in explicit syntaxes.
fn long_vr(vr: [u8; 2]) -> bool {
    matches!(
        &vr,
        b"OB"
            | b"OD"
            | b"OF"
            | b"OL"
            | b"OV"
            | b"OW"
            | b"SQ"
            | b"SV"
            | b"UC"
            | b"UN"
            | b"UR"
            | b"UT"
            | b"UV"
    )
}

/// Whether an element is a sequence: by its VR, or in implicit VR by the
/// dictionary, as a parser decides.
fn is_sequence(tag: Tag, vr: Option<[u8; 2]>) -> bool {
    use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry};
    match vr {
        Some(vr) => &vr == b"SQ",
        None => dicom_dictionary_std::StandardDataDictionary
            .by_tag(tag)
            .is_some_and(|e| e.vr().relaxed() == dicom_core::VR::SQ),
    }
}

struct Walker<R> {
    r: BufReader<R>,
    pos: u64,
    len: u64,
}

impl<R: Read + Seek> Walker<R> {
    fn remaining(&self) -> u64 {
        self.len.saturating_sub(self.pos)
    }

    /// Reads `N` bytes, or `None` at the end of the file.
    fn bytes<const N: usize>(&mut self) -> Option<[u8; N]> {
        let mut b = [0u8; N];
        self.r.read_exact(&mut b).ok()?;
        self.pos += N as u64;
        Some(b)
    }

    fn u16(&mut self, be: bool) -> Option<u16> {
        self.bytes::<2>().map(|b| {
            if be {
                u16::from_be_bytes(b)
            } else {
                u16::from_le_bytes(b)
            }
        })
    }

    fn u32(&mut self, be: bool) -> Option<u32> {
        self.bytes::<4>().map(|b| {
            if be {
                u32::from_be_bytes(b)
            } else {
                u32::from_le_bytes(b)
            }
        })
    }

    fn skip(&mut self, n: u32) -> std::io::Result<()> {
        self.r.seek_relative(n as i64)?;
        self.pos += n as u64;
        Ok(())
    }

    /// One element header: tag, VR (if explicit) and length.
    fn header(&mut self, syntax: Syntax) -> Option<(Tag, Option<[u8; 2]>, u32)> {
        let be = syntax == Syntax::ExplicitBe;
        let group = self.u16(be)?;
        let element = self.u16(be)?;
        let tag = Tag(group, element);
        // Items and delimiters carry no VR in any syntax; the 0002 group is
        // always explicit little endian (handled by the caller).
        if group == 0xFFFE || syntax == Syntax::ImplicitLe {
            return Some((tag, None, self.u32(be)?));
        }
        let vr = self.bytes::<2>()?;
        // dicom-rs reads bytes that name no VR as UN, whose length has 4
        // bytes after 2 reserved ones: walk them the same way, or a garbled
        // VR hides a huge declared length from the check (found by fuzzing).
        let unknown = dicom_core::VR::from_binary(vr).is_none();
        let len = if unknown || long_vr(vr) {
            self.bytes::<2>()?;
            self.u32(be)?
        } else {
            self.u16(be)? as u32
        };
        Some((tag, Some(vr), len))
    }

    fn check(&self, tag: Tag, len: u32, in_pixel_data: bool, ts: &str) -> Result<(), LengthError> {
        if len as u64 > self.remaining() {
            return Err(LengthError {
                tag,
                in_pixel_data,
                len,
                offset: self.pos,
                remaining: self.remaining(),
                transfer_syntax: ts.to_string(),
                misfit_vr: None,
            });
        }
        Ok(())
    }

    /// Refuses a length that is not a whole number of a fixed-size VR's
    /// values: parsers read such an element past its end and lose their
    /// place, taking garbage for the next lengths (found by fuzzing: an SH
    /// turned SL with 2 bytes cost 700 MB).
    fn check_vr(
        &self,
        tag: Tag,
        vr: Option<[u8; 2]>,
        len: u32,
        ts: &str,
    ) -> Result<(), LengthError> {
        let Some(vr) = vr else { return Ok(()) };
        let size = match &vr {
            b"SS" | b"US" | b"OW" => 2,
            b"SL" | b"UL" | b"FL" | b"AT" | b"OF" | b"OL" => 4,
            b"FD" | b"SV" | b"UV" | b"OD" | b"OV" => 8,
            _ => return Ok(()),
        };
        if len == UNDEFINED || len.is_multiple_of(size) {
            return Ok(());
        }
        Err(LengthError {
            tag,
            in_pixel_data: false,
            len,
            offset: self.pos,
            remaining: self.remaining(),
            transfer_syntax: ts.to_string(),
            misfit_vr: Some((String::from_utf8_lossy(&vr).into_owned(), size)),
        })
    }
}

/// Walks the element headers of a DICOM Part 10 stream of `file_len` bytes
/// (preamble, "DICM", meta group, data set) without reading the values, and
/// refuses any defined length longer than the rest of the file. Elements of
/// undefined length (sequences, items, encapsulated pixel data) are entered,
/// defined-length ones skipped whole. Returns `Ok(None)` when the stream does
/// not start like a Part 10 file or a bare data set
/// ([`looks_like_bare_dataset`]; left to the parser to report); a deflated
/// data set is not walked.
pub fn scan_layout<R: Read + Seek>(r: R, file_len: u64) -> Result<Option<Layout>, LengthError> {
    let mut w = Walker {
        r: BufReader::new(r),
        pos: 0,
        len: file_len,
    };
    let mut head = [0u8; 132];
    let head_len = read_up_to(&mut w.r, &mut head);
    let (start, bare) = if head_len == 132 && &head[128..132] == b"DICM" {
        (132, false)
    } else if head_len >= 4 && &head[0..4] == b"DICM" {
        (4, false)
    } else if looks_like_bare_dataset(&head[..head_len], file_len) {
        (0, true)
    } else {
        return Ok(None);
    };
    if w.r.seek(SeekFrom::Start(start)).is_err() {
        return Ok(None);
    }
    w.pos = start;
    // File meta group: explicit VR little endian, group 0002 (none in a bare
    // data set, which is implicit VR little endian throughout).
    let ts = if bare {
        IMPLICIT_LE.to_string()
    } else {
        match read_meta_group(&mut w)? {
            Some(ts) => ts,
            None => return Ok(None),
        }
    };
    let mut layout = Layout {
        file_len,
        transfer_syntax: ts.clone(),
        pixel_data_len: None,
    };
    if DEFLATED.contains(&ts.as_str()) {
        return Ok(Some(layout));
    }
    let base = match ts.as_str() {
        IMPLICIT_LE => Syntax::ImplicitLe,
        EXPLICIT_BE => Syntax::ExplicitBe,
        _ => Syntax::ExplicitLe,
    };
    // Open containers (sequences and items), each with the syntax inside it
    // (an undefined-length UN holds implicit VR little endian), whether it is
    // the top-level PixelData, and where it ends when its length is defined.
    // Defined-length sequences and items are walked too: a parser reads the
    // elements inside them, so their lengths need the same check.
    let mut open: Vec<(Syntax, bool, Option<u64>)> = Vec::new();
    loop {
        while open
            .last()
            .is_some_and(|c| c.2.is_some_and(|end| w.pos >= end))
        {
            open.pop();
        }
        let syntax = open.last().map_or(base, |c| c.0);
        let in_pixel_data = open.first().is_some_and(|c| c.1);
        let Some((tag, vr, len)) = w.header(syntax) else {
            break;
        };
        if tag.group() == 0xFFFE {
            match tag.element() {
                0xE000 if len == UNDEFINED => open.push((syntax, in_pixel_data, None)),
                0xE000 => {
                    w.check(tag, len, in_pixel_data, &ts)?;
                    if in_pixel_data {
                        // A fragment: bytes, not elements.
                        if w.skip(len).is_err() {
                            break;
                        }
                    } else {
                        open.push((syntax, false, Some(w.pos + len as u64)));
                    }
                }
                // Item or sequence delimiter: closes the innermost container.
                0xE00D | 0xE0DD => {
                    open.pop();
                }
                // No other element of group FFFE exists; a parser still takes
                // its length (a garbled delimiter declared 3.7 GB, found by
                // fuzzing).
                _ => {
                    w.check(tag, len, in_pixel_data, &ts)?;
                    if w.skip(len).is_err() {
                        break;
                    }
                }
            }
            continue;
        }
        let top_pixel_data = tag == PIXEL_DATA && open.is_empty();
        if len == UNDEFINED {
            if top_pixel_data {
                layout.pixel_data_len = Some(None);
            }
            let inner = if vr == Some(*b"UN") {
                Syntax::ImplicitLe
            } else {
                syntax
            };
            open.push((inner, top_pixel_data, None));
            continue;
        }
        if top_pixel_data {
            layout.pixel_data_len = Some(Some(len));
        }
        w.check(tag, len, in_pixel_data || top_pixel_data, &ts)?;
        if !top_pixel_data {
            w.check_vr(tag, vr, len, &ts)?;
        }
        if is_sequence(tag, vr) {
            open.push((syntax, false, Some(w.pos + len as u64)));
            continue;
        }
        if w.skip(len).is_err() {
            break;
        }
    }
    Ok(Some(layout))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// Preamble, "DICM", a meta group naming `ts`, then `body`.
    fn file(ts: &str, body: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; 128];
        b.extend(b"DICM");
        let mut uid = ts.as_bytes().to_vec();
        if uid.len() % 2 == 1 {
            uid.push(0);
        }
        b.extend([0x02, 0x00, 0x10, 0x00, b'U', b'I']);
        b.extend((uid.len() as u16).to_le_bytes());
        b.extend(uid);
        b.extend(body);
        b
    }

    fn explicit(tag: (u16, u16), vr: &[u8; 2], value: &[u8], declared: Option<u32>) -> Vec<u8> {
        let mut b = tag.0.to_le_bytes().to_vec();
        b.extend(tag.1.to_le_bytes());
        b.extend(vr);
        let len = declared.unwrap_or(value.len() as u32);
        if long_vr(*vr) {
            b.extend([0, 0]);
            b.extend(len.to_le_bytes());
        } else {
            b.extend((len as u16).to_le_bytes());
        }
        b.extend(value);
        b
    }

    fn scan(bytes: &[u8]) -> Result<Option<Layout>, LengthError> {
        scan_layout(Cursor::new(bytes), bytes.len() as u64)
    }

    const EXPLICIT_LE: &str = "1.2.840.10008.1.2.1";

    #[test]
    fn a_sound_file_gives_its_pixel_data_length() {
        let mut body = explicit((0x0028, 0x0010), b"US", &[4, 0], None);
        body.extend(explicit((0x7FE0, 0x0010), b"OW", &[0; 24], None));
        let layout = scan(&file(EXPLICIT_LE, &body)).unwrap().unwrap();
        assert_eq!(layout.transfer_syntax, EXPLICIT_LE);
        assert_eq!(layout.pixel_data_len, Some(Some(24)));
    }

    #[test]
    fn a_length_beyond_the_file_is_refused() {
        let body = explicit((0x7FE0, 0x0010), b"OW", &[0; 24], Some(0xFFFF_FFF0));
        let err = scan(&file(EXPLICIT_LE, &body)).unwrap_err();
        assert_eq!(
            (err.tag, err.len, err.remaining),
            (PIXEL_DATA, 0xFFFF_FFF0, 24)
        );
        assert!(
            err.to_string()
                .starts_with("PixelData (7FE0,0010) declares 4294967280 bytes"),
            "{err}"
        );
    }

    #[test]
    fn explicit_data_read_as_implicit_is_refused() {
        // The VR and length bytes of (0008,0005) CS read as a 4-byte length.
        let mut body = explicit((0x0008, 0x0005), b"CS", b"ISO_IR 100", None);
        body.extend(explicit((0x7FE0, 0x0010), b"OW", &[0; 24], None));
        let err = scan(&file(IMPLICIT_LE, &body)).unwrap_err();
        assert_eq!(err.tag, Tag(0x0008, 0x0005));
        assert!(err.to_string().contains("1.2.840.10008.1.2 "), "{err}");
    }

    #[test]
    fn sequences_and_fragments_are_walked() {
        // An undefined-length sequence holding an icon PixelData, then
        // encapsulated PixelData with a truncated fragment.
        let mut body = explicit((0x0088, 0x0200), b"SQ", &[], Some(UNDEFINED));
        body.extend([0xFE, 0xFF, 0x00, 0xE0, 0xFF, 0xFF, 0xFF, 0xFF]);
        body.extend(explicit((0x7FE0, 0x0010), b"OB", &[0; 4], None));
        body.extend([0xFE, 0xFF, 0x0D, 0xE0, 0, 0, 0, 0]);
        body.extend([0xFE, 0xFF, 0xDD, 0xE0, 0, 0, 0, 0]);
        body.extend(explicit((0x7FE0, 0x0010), b"OB", &[], Some(UNDEFINED)));
        body.extend([0xFE, 0xFF, 0x00, 0xE0, 0, 0, 0, 0]);
        let whole = file("1.2.840.10008.1.2.5", &body);
        assert_eq!(scan(&whole).unwrap().unwrap().pixel_data_len, Some(None));
        let mut cut = whole.clone();
        cut.extend([0xFE, 0xFF, 0x00, 0xE0, 100, 0, 0, 0, 1, 2]);
        let err = scan(&cut).unwrap_err();
        assert!(err.in_pixel_data, "{err:?}");
        assert!(
            err.to_string()
                .starts_with("a pixel data fragment declares 100 bytes"),
            "{err}"
        );
    }

    #[test]
    fn a_stream_without_dicm_is_left_to_the_parser() {
        assert_eq!(scan(&[0u8; 200]).unwrap(), None);
        assert_eq!(scan(&[0u8; 20]).unwrap(), None);
    }
}
