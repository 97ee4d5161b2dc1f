//! Fuzzes the reply and request framers: any bytes, split at an input-chosen point, must
//! frame and parse without panicking.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/pose.rs"]
mod pose;
#[path = "../../src/arm/dobot/proto.rs"]
mod proto;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let cut = data.first().map_or(0, |b| usize::from(*b) % (data.len() + 1));
    let mut replies = proto::ReplyFramer::new();
    let mut requests = proto::RequestFramer::new();
    for chunk in [&data[..cut], &data[cut..]] {
        replies.push(chunk);
        // Each call consumes input or returns Ok(None); bound the loop all the same.
        for _ in 0..=data.len() {
            match replies.next_reply() {
                Ok(None) => break,
                Ok(Some(r)) => {
                    let _ = (r.numbers(), r.pose(), r.joints_deg(), r.integer(), r.error_id_lists(), r.echo_name());
                    let _ = proto::Reply::parse(&r.encode());
                }
                Err(_) => {}
            }
        }
        requests.push(chunk);
        for _ in 0..=data.len() {
            match requests.next_call() {
                Ok(None) => break,
                Ok(Some(call)) => {
                    if let Ok(req) = proto::Request::from_call(&call) {
                        let _ = req.encode();
                    }
                }
                Err(_) => {}
            }
        }
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = proto::parse_error_id_lists(text);
        let _ = proto::parse_numbers(text);
    }
});
