//! Network glue shared by the three node crates: cluster certificates, QUIC endpoints and
//! control-message streams. It lives in `common` so the binaries do not each grow a copy; the
//! protocol logic itself stays in the sans-IO modules.

pub mod cluster;
pub mod framed;
pub mod quic;
