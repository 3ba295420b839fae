//! The `firmware-sim` binary serves real ptys and a Unix socket that speak the protocols.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Command, Stdio};
use std::time::Duration;

use filmscope_core::proto::fscl::{self, kind, Decoded, Header, Leader, Trigger};
use filmscope_core::proto::zaber;

#[test]
fn binary_prints_ports_that_answer_zaber_and_fscl() {
    let dir = std::env::temp_dir().join(format!("fsim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let sock = dir.join("cam.sock");
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenes/rig-tiny.toml"
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_firmware-sim"))
        .args([scene, "--speed", "100", "--unix"])
        .arg(&sock)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn");
    let mut out = BufReader::new(child.stdout.take().expect("stdout"));
    let mut field = |want: &str| {
        let mut line = String::new();
        out.read_line(&mut line).expect("line");
        let (k, v) = line
            .trim()
            .split_once(char::is_whitespace)
            .expect("key value");
        assert_eq!(k, want);
        v.trim().to_owned()
    };
    let stage = field("stage");
    let _filter = field("filter");
    let camera = field("camera");
    let mut port = serialport::new(&stage, 115_200)
        .timeout(Duration::from_millis(500))
        .open()
        .expect("open the stage pty");
    let cmd = zaber::command(1, 1, Some(5), "get pos").expect("cmd");
    port.write_all(cmd.as_bytes()).expect("write");
    let mut reply = Vec::new();
    let mut b = [0u8; 1];
    while !reply.ends_with(b"\n") {
        port.read_exact(&mut b).expect("reply byte");
        reply.push(b[0]);
    }
    let text = String::from_utf8_lossy(&reply).into_owned();
    match zaber::parse(&text) {
        Ok(zaber::Message::Reply(r)) => {
            assert_eq!(
                (r.id, r.warning_str()),
                (Some(5), "WR"),
                "not homed yet: {text}"
            )
        }
        other => panic!("{other:?} from {text:?}"),
    }
    let path = camera.strip_prefix("unix:").expect("unix camera");
    let mut s = std::os::unix::net::UnixStream::connect(path).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(5)))
        .expect("timeout");
    let t = Trigger {
        angle_mdeg: 10_000,
        wavelength_pm: 550_000,
        band: 0,
    };
    let h = Header {
        kind: kind::TRIGGER,
        flags: 0,
        seq: 0,
        frame_id: 42,
    };
    let mut msg = [0u8; fscl::message_len(Trigger::LEN)];
    let n = fscl::encode(&mut msg, h, &t.to_bytes()).expect("encode");
    s.write_all(&msg[..n]).expect("trigger");
    let mut buf = vec![0u8; 64];
    s.read_exact(&mut buf).expect("leader bytes");
    match fscl::decode(&buf, 1024) {
        Decoded::Message {
            header, payload, ..
        } => {
            assert_eq!((header.kind, header.frame_id), (kind::LEADER, 42));
            let l = Leader::parse(payload).expect("leader");
            assert_eq!(
                (l.width, l.expected_rows, l.wavelength_pm),
                (32, 24, 550_000)
            );
        }
        other => panic!("{other:?}"),
    }
    drop(child.stdin.take());
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
