//! The producer driven through its C functions, as a consumer drives it.

use super::*;
use handeye_gige::decode::pfnc;

/// The tests that set `HANDEYE_SIM_CAMERA_ARGS` or use the library's one global state run
/// one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// The camera.xml register `AcquisitionStart` writes (`AcquisitionStartReg`).
const ACQ_START_REG: u64 = 0xA014;

fn ok(code: GcError) {
    let (c, text) = LAST_ERROR.with(|e| e.borrow().clone());
    assert_eq!(code, err::SUCCESS, "last error {c}: {text}");
}

fn string(f: impl Fn(*mut c_char, *mut usize) -> GcError) -> String {
    let mut buf = [0u8; 256];
    let mut n = buf.len();
    ok(f(buf.as_mut_ptr().cast(), &mut n));
    String::from_utf8(buf[..n - 1].to_vec()).expect("utf-8")
}

fn number(f: impl Fn(*mut i32, *mut c_void, *mut usize) -> GcError) -> u64 {
    let mut v = [0u8; 8];
    let (mut ty, mut n) = (0, v.len());
    ok(f(&mut ty, v.as_mut_ptr().cast(), &mut n));
    let mut wide = [0u8; 8];
    wide[..n].copy_from_slice(&v[..n]);
    u64::from_ne_bytes(wide)
}

fn next_buffer(event: *mut c_void, timeout_ms: u64) -> Result<*mut c_void, GcError> {
    let mut data = [0u8; 16];
    let mut n = data.len();
    // SAFETY: `data` is writable for `n` bytes.
    let code = unsafe { EventGetData(event, data.as_mut_ptr().cast(), &mut n, timeout_ms) };
    if code != err::SUCCESS {
        return Err(code);
    }
    assert_eq!(n, 16);
    let h = usize::from_ne_bytes(data[..8].try_into().expect("8 bytes"));
    Ok(h as *mut c_void)
}

/// A consumer's whole session, as GenTL orders it: the one device by id, the XML through
/// the remote port, buffers announced both ways, no frame before `AcquisitionStart`, a
/// multi-part buffer holding the scene in millimetres, the queue rules, `EventKill`, and
/// everything closed again.
#[test]
fn a_consumer_session_from_init_to_close() {
    let _one = lock(&SERIAL);
    std::env::set_var(ARGS_ENV, "--test-pattern --width 32 --height 24");
    ok(GCInitLib());
    std::env::remove_var(ARGS_ENV);
    assert_eq!(GCInitLib(), err::RESOURCE_IN_USE);
    let mut tl = std::ptr::null_mut();
    // SAFETY (this and every call below): valid pointers to locals, strings NUL-terminated.
    ok(unsafe { TLOpen(&mut tl) });
    let mut n = 0u32;
    ok(unsafe { TLGetNumInterfaces(tl, &mut n) });
    assert_eq!(n, 1);
    let if_id = string(|b, n| unsafe { TLGetInterfaceID(tl, 0, b, n) });
    let mut iface = std::ptr::null_mut();
    let c_if = std::ffi::CString::new(if_id).expect("id");
    ok(unsafe { TLOpenInterface(tl, c_if.as_ptr(), &mut iface) });
    let dev_id = string(|b, n| unsafe { IFGetDeviceID(iface, 0, b, n) });
    assert_eq!(dev_id, "SIM0001");
    let mut dev = std::ptr::null_mut();
    let wrong = c"nope";
    assert_eq!(
        unsafe { IFOpenDevice(iface, wrong.as_ptr(), 3, &mut dev) },
        err::INVALID_ID
    );
    let c_dev = std::ffi::CString::new(dev_id).expect("id");
    ok(unsafe { IFOpenDevice(iface, c_dev.as_ptr(), 3, &mut dev) });
    let mut port = std::ptr::null_mut();
    ok(unsafe { DevGetPort(dev, &mut port) });
    let url =
        string(|b, n| unsafe { GCGetPortURLInfo(port, 0, 0, std::ptr::null_mut(), b.cast(), n) });
    assert!(url.starts_with("Local:handeye-sim.xml;"), "{url}");
    let len = number(|t, b, n| unsafe { GCGetPortURLInfo(port, 0, 8, t, b, n) }) as usize;
    let addr = number(|t, b, n| unsafe { GCGetPortURLInfo(port, 0, 7, t, b, n) });
    let mut xml = vec![0u8; len];
    let mut size = len;
    ok(unsafe { GCReadPort(port, addr, xml.as_mut_ptr().cast(), &mut size) });
    assert!(String::from_utf8_lossy(&xml).contains("<RegisterDescription"));
    // Stacked reads are the single reads, entry by entry; a null list is refused.
    let (mut head, mut tail) = ([0u8; 16], [0u8; 16]);
    let mut entries = [
        crate::ports::PortRegisterStackEntry {
            address: addr,
            buffer: head.as_mut_ptr().cast(),
            size: 16,
        },
        crate::ports::PortRegisterStackEntry {
            address: addr + 16,
            buffer: tail.as_mut_ptr().cast(),
            size: 16,
        },
    ];
    let mut n = entries.len();
    ok(unsafe { GCReadPortStacked(port, entries.as_mut_ptr(), &mut n) });
    assert_eq!([&head[..], &tail[..]].concat(), xml[..32]);
    assert_eq!(
        unsafe { GCReadPortStacked(port, std::ptr::null_mut(), &mut n) },
        err::INVALID_PARAMETER
    );
    // The system module's port holds its node map (issue 44), not the camera's registers.
    let mut word = [0u8; 4];
    let mut size = 4;
    assert_eq!(
        unsafe { GCReadPort(tl, 0xA000, word.as_mut_ptr().cast(), &mut size) },
        err::INVALID_ADDRESS
    );

    let mut ds = std::ptr::null_mut();
    let stream_id = c"Stream0";
    ok(unsafe { DevOpenDataStream(dev, stream_id.as_ptr(), &mut ds) });
    let payload = number(|t, b, n| unsafe { DSGetInfo(ds, 7, t, b, n) }) as usize;
    assert_eq!(payload, 32 * 24 * 12);
    let mut mine = vec![0u8; payload];
    let mut bufs = [std::ptr::null_mut(); 3];
    ok(unsafe {
        DSAnnounceBuffer(
            ds,
            mine.as_mut_ptr().cast(),
            payload,
            7 as *mut c_void,
            &mut bufs[0],
        )
    });
    for b in &mut bufs[1..] {
        ok(unsafe { DSAllocAndAnnounceBuffer(ds, payload, std::ptr::null_mut(), b) });
    }
    for b in bufs {
        ok(DSQueueBuffer(ds, b));
    }
    assert_eq!(DSQueueBuffer(ds, bufs[0]), err::RESOURCE_IN_USE);
    let mut event = std::ptr::null_mut();
    ok(unsafe { GCRegisterEvent(ds, abi::EVENT_NEW_BUFFER, &mut event) });
    ok(DSStartAcquisition(ds, 0, abi::GENTL_INFINITE));
    // The stream runs, the device does not: no frame.
    assert_eq!(next_buffer(event, 300), Err(err::TIMEOUT));
    let mut size = 4;
    ok(unsafe {
        GCWritePort(
            port,
            ACQ_START_REG,
            1u32.to_be_bytes().as_ptr().cast(),
            &mut size,
        )
    });
    let b = next_buffer(event, 5_000).expect("a buffer");
    assert_eq!(b, bufs[0], "the oldest queued buffer first");
    assert_eq!(
        number(|t, v, n| unsafe { DSGetBufferInfo(ds, b, 2, t, v, n) }),
        7
    );
    assert_eq!(
        number(|t, v, n| unsafe { DSGetBufferInfo(ds, b, 19, t, v, n) }),
        10
    );
    let mut parts = 0u32;
    ok(unsafe { DSGetNumBufferParts(ds, b, &mut parts) });
    assert_eq!(parts, 1);
    let part = |cmd| number(|t, v, n| unsafe { DSGetBufferPartInfo(ds, b, 0, cmd, t, v, n) });
    assert_eq!(part(3), u64::from(pfnc::COORD3D_ABC32F));
    assert_eq!(part(13), 4, "Range");
    assert_eq!((part(5), part(6), part(1)), (32, 24, payload as u64));
    assert_eq!(part(0), mine.as_ptr() as u64);
    let expected = handeye_gige::sim::SceneSource::new(32, 24).render();
    for (i, p) in expected.points.iter().enumerate() {
        let got: Vec<f32> = (0..3)
            .map(|k| {
                let o = 12 * i + 4 * k;
                f32::from_le_bytes(mine[o..o + 4].try_into().expect("4 bytes"))
            })
            .collect();
        if p.x.is_nan() {
            assert!(got.iter().all(|c| c.is_nan()), "point {i}: {got:?}");
        } else {
            assert_eq!(got, [p.x * 1000.0, p.y * 1000.0, p.z * 1000.0], "point {i}");
        }
    }
    // Delivered, not queued: revoking is refused until it is flushed out of the queues.
    let mut base = std::ptr::null_mut();
    let mut user = std::ptr::null_mut();
    assert_eq!(
        unsafe { DSRevokeBuffer(ds, bufs[1], &mut base, &mut user) },
        err::RESOURCE_IN_USE
    );
    ok(EventKill(event));
    assert_eq!(next_buffer(event, 5_000), Err(err::ABORT));
    ok(DSStopAcquisition(ds, 1));
    ok(DSFlushQueue(ds, 4));
    for b in bufs {
        ok(unsafe { DSRevokeBuffer(ds, b, &mut base, &mut user) });
    }
    assert_eq!(user as usize, 0);
    ok(GCUnregisterEvent(ds, abi::EVENT_NEW_BUFFER));
    ok(DSClose(ds));
    ok(DevClose(dev));
    ok(IFClose(iface));
    ok(TLClose(tl));
    ok(GCCloseLib());
    assert_eq!(unsafe { TLOpen(&mut tl) }, err::NOT_INITIALIZED);
}

#[test]
fn scene_options_come_from_the_environment_as_sim_camera_reads_them() {
    let _one = lock(&SERIAL);
    let parse = |s: &str| {
        use clap::Parser as _;
        EnvArgs::try_parse_from(shlex::split(s).expect("quotes")).map(|a| a.scene)
    };
    let a = parse("--robot 127.0.0.1 --width 320 --height 240 --serial 'A B'").expect("ok");
    assert_eq!((a.width, a.height, a.serial.as_str()), (320, 240, "A B"));
    assert_eq!(a.robot.as_deref(), Some("127.0.0.1"));
    let e = parse("--bind 127.0.0.1").expect_err("not a scene option");
    assert!(e.to_string().contains("--bind"), "{e}");
    // The failure GCInitLib reports names the variable and what it takes.
    std::env::set_var(ARGS_ENV, "--width 320 --loss 0.1");
    let f = scene_args().expect_err("--loss is the GigE camera's");
    std::env::remove_var(ARGS_ENV);
    assert_eq!(f.code, err::INVALID_PARAMETER);
    assert!(
        f.text
            .starts_with("HANDEYE_SIM_CAMERA_ARGS: unexpected argument '--loss'")
            && f.text.contains("handeye sim camera --help"),
        "{}",
        f.text
    );
}
