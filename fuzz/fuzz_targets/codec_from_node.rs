//! Node → master control frames (`protocol::codec`): length prefix, postcard body, every
//! validating constructor behind `checked`, control requests and input events included.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_protocol::{codec, FromNode};

fuzz_target!(|frame: &[u8]| {
    if let Ok(msg) = codec::decode_frame::<FromNode>(frame) {
        // What was accepted must travel again: the encoding a peer would send back decodes to
        // a message that encodes the same (bytes, so NaN payloads compare too).
        let once = codec::encode(&msg).expect("a decoded message re-encodes");
        let again: FromNode = codec::decode_frame(&once).expect("a re-encoded message decodes");
        assert_eq!(codec::encode(&again).expect("re-encodes"), once);
    }
});
