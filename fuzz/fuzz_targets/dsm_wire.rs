//! Render node → render node block requests (`protocol::dsm`): a length-prefixed postcard
//! request, and the header before each answered block.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_protocol::codec;
use tessera_protocol::dsm::{decode_block_header, encode_block_header, BlockRequest};

fuzz_target!(|frame: &[u8]| {
    if let Ok(request) = codec::decode_frame::<BlockRequest>(frame) {
        let once = codec::encode(&request).expect("a decoded request re-encodes");
        let again: BlockRequest = codec::decode_frame(&once).expect("a re-encoded request decodes");
        assert_eq!(again, request);
    }
    if let Some(head) = frame.first_chunk() {
        if let Ok((block, follows)) = decode_block_header(*head) {
            assert_eq!(encode_block_header(block, follows), *head);
        }
    }
});
