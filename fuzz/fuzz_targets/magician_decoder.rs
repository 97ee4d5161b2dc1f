//! Fuzzes the Dobot Magician packet framer and command/reply parsers: any bytes, split at an
//! input-chosen point, must frame and parse without panicking, and every packet framed must
//! encode back to bytes that frame to the same packet.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/arm/magician/proto.rs"]
mod proto;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let cut = data.first().map_or(0, |b| usize::from(*b) % (data.len() + 1));
    let mut framer = proto::PacketFramer::new();
    for chunk in [&data[..cut], &data[cut..]] {
        framer.push(chunk);
        // Each call consumes input or returns None; bound the loop all the same.
        for _ in 0..=data.len() {
            let Some(packet) = framer.next_packet() else { break };
            if let Ok(command) = proto::Command::from_packet(&packet) {
                let _ = command.encode();
            }
            for command in [
                proto::Command::GetDeviceVersion,
                proto::Command::GetPose,
                proto::Command::GetAlarmsState,
                proto::Command::GetQueuedCurrentIndex,
            ] {
                let _ = command.parse_reply(&packet);
            }
            let bytes = packet.encode().expect("a framed packet re-encodes");
            match proto::decode(&bytes) {
                proto::Decoded::Packet { packet: again, used } => {
                    assert_eq!(again, packet);
                    assert_eq!(used, bytes.len());
                }
                other => panic!("re-encoded packet does not frame: {other:?}"),
            }
        }
    }
});
