//! Sizes in bytes as people write them: `512MiB`, `2GiB`, `8KiB`, `1.5GB`, `4096`.

/// Parses a size: a number and an optional unit, binary (`KiB`, `MiB`, `GiB`, `TiB`, or `K`,
/// `M`, `G`, `T`) or decimal (`kB`, `MB`, `GB`, `TB`), `B` for bytes; case and spaces do not
/// matter.
///
/// # Examples
///
/// ```
/// use tessera_cli::bytes::parse_bytes;
/// assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
/// assert_eq!(parse_bytes("2 GiB"), Ok(2 << 30));
/// assert_eq!(parse_bytes("1.5GB"), Ok(1_500_000_000));
/// assert_eq!(parse_bytes("8k"), Ok(8192));
/// assert!(parse_bytes("lots").is_err());
/// ```
///
/// # Errors
/// Text that is not a non-negative number with a known unit, or a size past 2^64.
pub fn parse_bytes(text: &str) -> Result<u64, String> {
    let bad =
        || format!("`{text}` is not a size in bytes (such as 512MiB, 2GiB, 8KiB, 1.5GB or 4096)");
    let t = text.trim().to_ascii_lowercase();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number.parse().map_err(|_| bad())?;
    let scale: f64 = match unit.trim() {
        "" | "b" => 1.0,
        "k" | "kib" => 1024.0,
        "m" | "mib" => 1024.0 * 1024.0,
        "g" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tib" => 1024f64.powi(4),
        "kb" => 1e3,
        "mb" => 1e6,
        "gb" => 1e9,
        "tb" => 1e12,
        _ => return Err(bad()),
    };
    let bytes = (value * scale).round();
    if !bytes.is_finite() || bytes < 0.0 || bytes >= u64::MAX as f64 {
        return Err(bad());
    }
    Ok(bytes as u64)
}

/// A size as people read it: `512.0 MiB`.
pub fn show_bytes(bytes: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < units.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", units[unit])
    }
}
