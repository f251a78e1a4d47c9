//! A pass over a DICOM file's element headers before dicom-rs reads it. dicom-object 0.8 and
//! dicom-parser 0.8 allocate and zero an element's claimed length before reading its value, so
//! a 400-byte slice claiming a 4 GB element cost 4 GB of memory (found by fuzzing,
//! `fuzz/fuzz_targets/volume_dicom.rs`). Here every defined length must fit in what is left of
//! the file; the headers are walked as dicom-rs walks them, into sequences and items.

use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
use dicom_core::{Tag, VR};
use dicom_dictionary_std::StandardDataDictionary;

const IMPLICIT_LE: &str = "1.2.840.10008.1.2";
/// Data sets this pass does not walk: big-endian, or deflated.
const EXPLICIT_BE: &str = "1.2.840.10008.1.2.2";
const DEFLATED: &str = "1.2.840.10008.1.2.1.99";
const UNDEFINED: u32 = u32::MAX;

/// `Err` names the first element whose length runs past the end of `bytes`. A file that is not
/// DICOM is left to dicom-rs, and so is a big-endian or deflated data set after its meta group.
pub(super) fn check(bytes: &[u8]) -> Result<(), String> {
    let start = if bytes.get(128..132) == Some(b"DICM") {
        132
    } else if bytes.get(..4) == Some(b"DICM") {
        4
    } else {
        return Ok(());
    };
    let mut at = Reader { bytes, at: start };
    // The meta group: explicit VR little endian, its length in its first element.
    let Some((Tag(2, 0), _, 4)) = at.header(true) else {
        return Ok(());
    };
    let Some(group_length) = at
        .take(4)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
    else {
        return Ok(());
    };
    // dicom-object reads whole elements until it has read `group_length` bytes, so the data
    // set starts where the last of them ends, which need not be that many bytes on.
    let data_set = at.at.saturating_add(group_length as usize);
    let mut syntax = String::new();
    while at.at < data_set.min(bytes.len()) {
        let Some((tag, _, len)) = at.header(true) else {
            return Ok(());
        };
        let value = at.value(tag, len)?;
        if tag == Tag(2, 0x10) {
            // The UID's digits and dots: dicom-rs trims what follows more widely than `\0`
            // and spaces (a no-break space too), and must not see another syntax than this.
            let uid = value
                .iter()
                .take_while(|b| b.is_ascii_digit() || **b == b'.');
            syntax = uid.map(|&b| char::from(b)).collect();
        }
    }
    // Compressed syntaxes keep their data sets in explicit VR little endian too, and dicom-rs
    // reads those (fragments and all) before the loader refuses them.
    let explicit = match syntax.as_str() {
        IMPLICIT_LE => false,
        EXPLICIT_BE | DEFLATED => return Ok(()),
        _ => true,
    };
    // Inside encapsulated pixel data, items hold fragments, not elements.
    let mut fragments = false;
    while let Some((tag, vr, len)) = at.header(explicit) {
        match tag {
            Tag(0xFFFE, 0xE000) if fragments => {
                at.value(tag, len)?;
            }
            Tag(0xFFFE, 0xE0DD) => fragments = false,
            Tag(0xFFFE, _) => {}
            _ if len == UNDEFINED => fragments = tag == Tag(0x7FE0, 0x0010),
            // A sequence's items are walked like its parent's elements.
            _ if vr == VR::SQ => {}
            _ => {
                at.value(tag, len)?;
            }
        }
    }
    Ok(())
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let out = self.bytes.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(out)
    }

    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|b| u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self) -> Option<u32> {
        self.take(4)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
    }

    /// The next header as dicom-encoding 0.8 decodes it (`explicit_le` / `implicit_le`), or
    /// `None` at the end of the bytes.
    fn header(&mut self, explicit: bool) -> Option<(Tag, VR, u32)> {
        let tag = Tag(self.u16()?, self.u16()?);
        if tag.0 == 0xFFFE {
            return Some((tag, VR::UN, self.u32()?));
        }
        if !explicit {
            let vr = match StandardDataDictionary.by_tag(tag).map(|e| e.vr()) {
                Some(VirtualVr::Exact(vr)) => vr,
                _ => VR::UN,
            };
            return Some((tag, vr, self.u32()?));
        }
        let code = self.take(2)?;
        let vr = VR::from_binary([code[0], code[1]]).unwrap_or(VR::UN);
        use VR::*;
        let len = match vr {
            OB | OD | OF | OL | OW | SQ | UC | UR | UT | UN => {
                self.take(2)?;
                self.u32()?
            }
            _ => u32::from(self.u16()?),
        };
        Some((tag, vr, len))
    }

    /// Skips the value of `len` bytes, which must be defined and fit in the file.
    fn value(&mut self, tag: Tag, len: u32) -> Result<&[u8], String> {
        let left = self.bytes.len() - self.at.min(self.bytes.len());
        if len == UNDEFINED && tag.0 == 2 {
            return Err(format!(
                "element {tag} of the meta group has an undefined length"
            ));
        }
        self.take(len as usize).ok_or_else(|| {
            format!("element {tag} claims {len} bytes, but only {left} are left in the file")
        })
    }
}
