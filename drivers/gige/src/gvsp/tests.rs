use std::net::{Ipv4Addr, UdpSocket};
use std::time::{Duration, Instant};

use super::*;

fn block(id: u64, multipart: bool) -> Block {
    let w = 40;
    let h = 30;
    let pf = 0x026000C0;
    let data: Vec<u8> = (0..w * h * 12).map(|i| (i % 251) as u8).collect();
    let info = PartInfo {
        data_type: PART_3D_IMAGE,
        length: data.len() as u64,
        pixel_format: pf,
        purpose: 4,
        width: w,
        height: h,
        padding_x: 0,
    };
    let mut parts = vec![(info, data)];
    if multipart {
        let c: Vec<u8> = (0..w * h * 2).map(|i| (i % 7) as u8).collect();
        parts.push((
            PartInfo {
                data_type: PART_CONFIDENCE,
                length: c.len() as u64,
                pixel_format: 0x011000C7,
                purpose: 6,
                width: w,
                height: h,
                padding_x: 0,
            },
            c,
        ));
    }
    Block {
        block_id: id,
        timestamp: 99,
        parts,
        multipart,
    }
}

fn receiver(extended: bool, resend: bool) -> StreamReceiver {
    let cfg = StreamConfig {
        packet_size: 400,
        extended,
        resend,
        max_frame_bytes: 1 << 20,
        ..StreamConfig::default()
    };
    StreamReceiver::bind(
        Ipv4Addr::LOCALHOST,
        "127.0.0.1:9".parse().expect("addr"),
        cfg,
    )
    .expect("bind")
}

#[test]
fn frames_reassemble_standard_and_multipart_with_wraparound() {
    for (ext, mp) in [(false, false), (true, false), (true, true)] {
        let mut r = receiver(ext, true);
        let now = Instant::now();
        let ids: &[u64] = if ext {
            &[1 << 40, (1 << 40) + 1]
        } else {
            &[65534, 65535, 1, 2]
        };
        for &id in ids {
            let b = block(id, mp);
            let mut pk = packetize(&b, 400, ext).expect("packetize");
            pk.swap(2, 5); // reordering
            for p in &pk {
                r.handle(p, now);
            }
            let f = r.ready.pop_front().expect("frame");
            assert!(f.complete, "{ext} {mp} {id}");
            assert_eq!(f.block_id, id);
            assert_eq!(f.parts.len(), b.parts.len());
            for ((pi, pd), (bi, bd)) in f.parts.iter().zip(&b.parts) {
                assert_eq!(pd, bd);
                assert_eq!(pi.pixel_format, bi.pixel_format);
                assert_eq!((pi.width, pi.height), (bi.width, bi.height));
            }
        }
    }
}

#[test]
fn packetize_into_recycled_buffers_matches_fresh_packets() {
    // Recycled from a bigger multi-part frame with other contents and packet size.
    let mut reused = packetize(&block(9, true), 300, true).expect("p");
    let n_old = reused.len();
    for (ext, mp) in [(false, false), (true, true)] {
        let b = block(4, mp);
        packetize_into(&b, 400, ext, &mut reused).expect("packetize_into");
        assert_eq!(reused, packetize(&b, 400, ext).expect("packetize"));
    }
    assert!(reused.len() < n_old);
}

#[test]
fn socket_path_reads_batches_and_ignores_oversized_datagrams() {
    let mut r = receiver(false, true);
    let to = r.local_addr().expect("addr");
    let tx = UdpSocket::bind("127.0.0.1:0").expect("bind");
    // Longer than a receive slot for 400-byte packets: truncated, so ignored.
    tx.send_to(&[0x55; 5000], to).expect("send");
    let pk = packetize(&block(7, false), 400, false).expect("packetize");
    for p in &pk {
        tx.send_to(p, to).expect("send");
    }
    let f = r.next_frame(Duration::from_secs(2)).expect("frame");
    assert!(f.complete);
    assert_eq!(f.block_id, 7);
    assert_eq!(f.parts[0].1, block(7, false).parts[0].1);
    assert_eq!(r.stats().ignored_packets, 1);
    assert_eq!(r.stats().packets, pk.len() as u64);
}

#[test]
fn lost_packets_are_detected_and_frame_closes_incomplete() {
    let mut r = receiver(false, false);
    let now = Instant::now();
    let pk = packetize(&block(5, false), 400, false).expect("packetize");
    for (i, p) in pk.iter().enumerate() {
        if i != 3 {
            r.handle(p, now);
        }
    }
    assert!(r.ready.is_empty());
    r.housekeeping(now + Duration::from_secs(1));
    let f = r.ready.pop_front().expect("closed");
    assert!(!f.complete);
    assert_eq!(f.missing_packets, 1);
}

/// Issue 36: a leader that claims more than the payload carries (twice the image over the
/// packets of one, closed by its trailer) is an incomplete frame, standard and multipart: the
/// missing half is not zeros counted as points.
#[test]
fn issue_36_a_payload_short_of_its_leader_is_incomplete() {
    for mp in [false, true] {
        // Multi-part needs extended ids.
        let mut r = receiver(mp, false);
        let now = Instant::now();
        let small = block(7, mp);
        let mut big = small.clone();
        for (info, data) in &mut big.parts {
            info.height *= 2;
            info.length *= 2;
            data.extend(data.clone());
        }
        let mut pk = packetize(&small, 400, mp).expect("packetize");
        pk[0] = packetize(&big, 400, mp).expect("packetize")[0].clone();
        for p in &pk {
            r.handle(p, now);
        }
        r.housekeeping(now + Duration::from_secs(1));
        let f = r.ready.pop_front().expect("frame");
        assert!(!f.complete, "multipart {mp}");
    }
}

/// Fuzz target `gvsp` (hal::fuzz): mutated leader, payload and trailer packets (single- and
/// multi-part, standard and extended ids) fed to one receiver: a header and leader parse or
/// are refused with a message; the receiver never holds more frames than its budget and lets
/// every one go.
#[test]
fn fuzz_gvsp() {
    let mut seeds = packetize(&block(3, false), 400, false).expect("p");
    seeds.extend(packetize(&block(4, true), 400, true).expect("p"));
    let mut r = receiver(true, true);
    let now = Instant::now();
    // A frame's buffers stay within the receiver's budget (1 MiB here), whatever the packets.
    handeye_hal::fuzz::Target::new("gvsp", seeds)
        .allocation_cap(0, r.cfg.max_frame_bytes)
        .run(|b| {
            r.handle(b, now);
            assert!(r.frames.len() <= r.cfg.max_frames_in_flight.max(1));
            assert!(r.ready.len() <= r.cfg.max_frames_in_flight.max(1));
            let (h, body) = Header::parse(b).map_err(|e| e.to_string())?;
            if h.format == FORMAT_LEADER {
                Leader::parse(&h, body).map_err(|e| e.to_string())?;
            }
            Ok::<(), String>(())
        });
    r.housekeeping(now + Duration::from_secs(5));
    assert!(r.frames.is_empty());
}

/// Issue 23 (found by the `gvsp` fuzz target): payload packets of a frame whose leader was
/// refused (or lost) grew its buffer by `Vec`'s doubling, reserving up to twice the frame
/// budget; now never more than the budget.
#[test]
fn issue_23_frame_buffer_never_reserves_past_the_budget() {
    let budget = 10_000;
    let mut r = receiver(false, false);
    r.cfg.max_frame_bytes = budget;
    let packets = packetize(&block(3, false), 400, false).expect("p");
    let now = Instant::now();
    let (_, largest) = handeye_hal::fuzz::largest_allocation(|| {
        for p in &packets {
            let (h, _) = Header::parse(p).expect("header");
            // The 14 400-byte frame's leader is over budget: only its payload packets.
            if h.format == FORMAT_PAYLOAD {
                r.handle(p, now);
            }
        }
    });
    let largest = largest.expect("TrackingAlloc is the test binary's allocator");
    assert!(
        largest <= budget,
        "reserved {largest} bytes for a {budget}-byte budget"
    );
}

/// Issue 23 (found by the `gvsp` fuzz target): finished frames nobody read yet queued without
/// end; now at most `max_frames_in_flight` wait, the oldest dropped and counted.
#[test]
fn issue_23_unread_frames_are_bounded() {
    let mut r = receiver(false, false);
    let now = Instant::now();
    for id in 1..=40 {
        for p in packetize(&block(id, false), 400, false).expect("p") {
            r.handle(&p, now);
        }
    }
    let cap = r.cfg.max_frames_in_flight;
    assert_eq!(r.ready.len(), cap);
    assert_eq!(r.stats().complete_frames, 40);
    assert_eq!(r.stats().dropped_frames, 40 - cap as u64);
    // The newest are kept.
    assert_eq!(r.ready.back().map(|f| f.block_id), Some(40));
}

/// Issue 16: structure-aware huge counts — every 16- and 32-bit field of a leader, data
/// and trailer packet set in turn to the largest values (sizes, part counts, packet and
/// block ids, offsets); the receiver stays within its frame budget and never panics.
#[test]
fn issue_16_huge_fields_in_every_packet_position() {
    let t0 = Instant::now();
    for (mp, ext) in [(false, false), (true, true)] {
        let packets = packetize(&block(5, mp), 400, ext).expect("p");
        let mut r = receiver(ext, true);
        let now = Instant::now();
        let picks = [0, 1, packets.len() - 1];
        for &k in &picks {
            let seed = &packets[k];
            for off in 0..seed.len().min(96) {
                for value in [u32::MAX, 0x7FFF_FFFF, 0x8000_0000, 0x0001_0000] {
                    let mut b = seed.clone();
                    for (i, byte) in value.to_be_bytes().iter().enumerate() {
                        if let Some(x) = b.get_mut(off + i) {
                            *x = *byte;
                        }
                    }
                    if let Ok((h, body)) = Header::parse(&b) {
                        let _ = Leader::parse(&h, body);
                    }
                    r.handle(&b, now);
                    assert!(r.frames.len() <= r.cfg.max_frames_in_flight.max(1));
                }
            }
        }
        r.housekeeping(now + Duration::from_secs(5));
    }
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
}

/// Issue 35: a chunk-only payload (payload type 4, no geometry in its leader) is a complete
/// frame of one chunk-data part, which splits back into its chunks; bad chunk tags are errors.
#[test]
fn chunk_only_payloads_reassemble_and_split() {
    let (a, b): (Vec<u8>, Vec<u8>) = ((0..3000).map(|i| i as u8).collect(), vec![7; 10]);
    let mut payload = Vec::new();
    push_chunk(&mut payload, 4, &a);
    push_chunk(&mut payload, 1, &b);
    let block = Block {
        block_id: 9,
        timestamp: 5,
        parts: vec![(
            PartInfo {
                data_type: PART_CHUNK,
                length: payload.len() as u64,
                ..PartInfo::default()
            },
            payload.clone(),
        )],
        multipart: false,
    };
    for ext in [false, true] {
        let mut r = receiver(ext, true);
        let mut pk = packetize(&block, 400, ext).expect("packetize");
        pk.swap(1, 3);
        for p in &pk {
            r.handle(p, Instant::now());
        }
        let f = r.ready.pop_front().expect("frame");
        assert!(f.complete, "{ext}");
        assert_eq!(f.parts.len(), 1);
        assert_eq!(f.parts[0].0.data_type, PART_CHUNK);
        assert_eq!(f.parts[0].1, payload);
        let chunks = split_chunks(&f.parts[0].1).expect("chunks");
        assert_eq!(chunks, vec![(4, a.as_slice()), (1, b.as_slice())]);
    }
    assert_eq!(split_chunks(&[]).expect("empty"), vec![]);
    for bad in [
        vec![1, 2, 3],
        vec![0, 0, 0, 4, 0xFF, 0xFF, 0xFF, 0xFF],
        [
            vec![0; 4],
            4u32.to_be_bytes().to_vec(),
            5u32.to_be_bytes().to_vec(),
        ]
        .concat(),
    ] {
        let e = split_chunks(&bad).expect_err("malformed").to_string();
        assert!(e.contains("chunk"), "{e}");
    }
}
