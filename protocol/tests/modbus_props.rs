//! Robustness of the Modbus RTU frame parsers (instruments.md §5): any bytes as the answer to
//! any request, or as a slave's receive buffer, give a classification and never a panic; a
//! frame made from the data sheet's layout is read back exactly, and any single flipped bit
//! in it is caught.

use proptest::prelude::*;
use protocol::modbus::*;

fn request() -> impl Strategy<Value = ReadRequest> {
    (
        any::<u8>(),
        prop_oneof![Just(3u8), Just(4u8), any::<u8>()],
        any::<u16>(),
        0u16..=130,
    )
        .prop_map(|(unit, function, start, count)| ReadRequest {
            unit,
            function,
            start,
            count,
        })
}

proptest! {
    #[test]
    fn random_bytes_never_panic(req in request(), bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = parse_response(&req, &bytes);
        let _ = parse_request(&bytes);
        // A slave's resync loop ends: each step consumes bytes or waits.
        let mut buf = bytes.clone();
        loop {
            match parse_request(&buf) {
                RequestParse::Incomplete => break,
                RequestParse::BadCrc => { buf.remove(0); }
                RequestParse::Request { len, .. } => { buf.drain(..len); }
            }
        }
    }

    #[test]
    fn random_bytes_after_a_valid_prefix_never_panic(
        req in request(),
        regs in prop::collection::vec(any::<u16>(), 0..125),
        cut in any::<prop::sample::Index>(),
        tail in prop::collection::vec(any::<u8>(), 0..20),
    ) {
        let mut f = encode_read_response(req.unit, req.function, &regs);
        f.truncate(cut.index(f.len() + 1));
        f.extend_from_slice(&tail);
        let _ = parse_response(&req, &f);
    }

    #[test]
    fn frames_read_back_and_bit_flips_are_caught(
        unit in 1u8..=247,
        function in prop_oneof![Just(READ_INPUT), Just(READ_HOLDING)],
        regs in prop::collection::vec(any::<u16>(), 1..=125),
        bit in any::<prop::sample::Index>(),
    ) {
        let req = ReadRequest { unit, function, start: 0, count: regs.len() as u16 };
        let f = encode_read_response(unit, function, &regs);
        prop_assert_eq!(parse_response(&req, &f), Response::Registers(regs.clone()));
        prop_assert_eq!(parse_request(&req.encode()), RequestParse::Request { req, len: 8 });
        let mut bad = f.clone();
        let b = bit.index(bad.len() * 8);
        bad[b / 8] ^= 1 << (b % 8);
        prop_assert_ne!(parse_response(&req, &bad), Response::Registers(regs));
    }
}
