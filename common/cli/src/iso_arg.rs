//! `--iso VALUE[:COLOUR[:OPACITY]]`: an iso-value with, optionally, how its surface looks.
//!
//! The colour is a name (`bone`, `skin`, `red`, `green`, `blue`, `yellow`, `white`, `grey`) or
//! linear `R,G,B` from 0 to 1; the opacity is from 0 to 1. What is left out takes the default
//! (`VolumeParams::iso_look`): a colour by the surface's place in the list, and with several
//! surfaces all but the highest value's translucent, so the inner one shows through.

use tessera_model::volume_params::{IsoLook, IsoValues, VolumeParamsError, MAX_ISO_VALUES};

/// One `--iso` as given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsoArg {
    /// The iso-value, in the data's own units.
    pub value: f32,
    /// Its colour and opacity, where given.
    pub look: IsoLook,
}

/// Colours `--iso` takes by name (linear RGB).
const NAMED: [(&str, [f32; 3]); 8] = [
    ("bone", [0.9, 0.86, 0.78]),
    ("skin", [0.85, 0.55, 0.45]),
    ("red", [0.8, 0.15, 0.12]),
    ("green", [0.2, 0.7, 0.25]),
    ("blue", [0.2, 0.35, 0.85]),
    ("yellow", [0.9, 0.8, 0.2]),
    ("white", [0.95, 0.95, 0.95]),
    ("grey", [0.5, 0.5, 0.5]),
];

/// Parses `VALUE[:COLOUR[:OPACITY]]`.
///
/// # Examples
/// ```
/// use tessera_cli::iso_arg::parse_iso;
///
/// let iso = parse_iso("-300:skin:0.3").unwrap();
/// assert_eq!((iso.value, iso.look.opacity), (-300.0, Some(0.3)));
/// assert_eq!(parse_iso("500:1,0.5,0").unwrap().look.color, Some([1.0, 0.5, 0.0]));
/// assert!(parse_iso("500:purple").unwrap_err().contains("bone"));
/// ```
pub fn parse_iso(text: &str) -> Result<IsoArg, String> {
    let mut parts = text.split(':');
    let value_text = parts.next().unwrap_or_default().trim();
    let value: f32 = value_text
        .parse()
        .ok()
        .filter(|v: &f32| v.is_finite())
        .ok_or_else(|| format!("`{value_text}` in `{text}` is not a finite number"))?;
    // `VALUE::OPACITY` keeps the default colour.
    let color = match parts.next().map(str::trim) {
        None | Some("") => None,
        Some(c) => Some(parse_color(c)?),
    };
    let opacity = parts
        .next()
        .map(|o| {
            o.trim()
                .parse::<f32>()
                .ok()
                .filter(|o| (0.0..=1.0).contains(o))
                .ok_or_else(|| format!("opacity `{o}` in `{text}` is not from 0 to 1"))
        })
        .transpose()?;
    if parts.next().is_some() {
        return Err(format!("`{text}` is not VALUE[:COLOUR[:OPACITY]]"));
    }
    Ok(IsoArg {
        value,
        look: IsoLook { color, opacity },
    })
}

fn parse_color(text: &str) -> Result<[f32; 3], String> {
    let name = text.trim().to_ascii_lowercase();
    if let Some((_, rgb)) = NAMED.iter().find(|(n, _)| *n == name) {
        return Ok(*rgb);
    }
    let parts: Vec<f32> = text
        .split(',')
        .filter_map(|c| c.trim().parse().ok())
        .filter(|c| (0.0..=1.0).contains(c))
        .collect();
    match parts[..] {
        [r, g, b] if text.split(',').count() == 3 => Ok([r, g, b]),
        _ => {
            let names: Vec<&str> = NAMED.iter().map(|(n, _)| *n).collect();
            Err(format!(
                "colour `{text}` is neither R,G,B (each 0 to 1) nor one of {}",
                names.join(", ")
            ))
        }
    }
}

/// The iso-values and their looks, in order.
///
/// # Errors
/// More than [`MAX_ISO_VALUES`] of them.
pub fn iso_params(
    isos: &[IsoArg],
) -> Result<(IsoValues, [IsoLook; MAX_ISO_VALUES]), VolumeParamsError> {
    let values: Vec<f32> = isos.iter().map(|i| i.value).collect();
    let iso = IsoValues::new(&values)?;
    let mut looks = [IsoLook::default(); MAX_ISO_VALUES];
    for (slot, arg) in looks.iter_mut().zip(isos) {
        *slot = arg.look;
    }
    Ok((iso, looks))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso_flags_take_a_colour_and_an_opacity_and_name_what_is_wrong() {
        assert_eq!(
            parse_iso("300").unwrap(),
            IsoArg {
                value: 300.0,
                look: IsoLook::default()
            }
        );
        let bone = parse_iso("500:bone:1").unwrap();
        assert_eq!(bone.look.color, Some([0.9, 0.86, 0.78]));
        assert_eq!(bone.look.opacity, Some(1.0));
        for (bad, says) in [
            ("x", "not a finite number"),
            ("1:2,3", "neither R,G,B"),
            ("1:red:1.5", "opacity `1.5`"),
            ("1:red:1:2", "VALUE[:COLOUR[:OPACITY]]"),
        ] {
            let e = parse_iso(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
        let (iso, looks) = iso_params(&[bone, parse_iso("-100::0.2").unwrap()]).unwrap();
        assert_eq!(iso.as_slice().len(), 2);
        assert_eq!(looks[0].opacity, Some(1.0));
        assert_eq!((looks[1].color, looks[1].opacity), (None, Some(0.2)));
    }
}
