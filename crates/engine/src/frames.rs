//! Building acyclic frames and recognising replies: shared by the direct `transact` path and
//! the RT thread (which matches mailbox and cyclic replies the same way).

use ether_ros_protocol::{self as wire, Command, FrameBuilder, MASTER_MAC, MAX_FRAME_LEN};

/// One datagram of a `transact` call: data to write, or a length to read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Request {
    /// The datagram command (APRD, FPWR, BRD, ...).
    pub cmd: Command,
    /// The datagram address (ADP and ADO, or a logical address).
    pub address: u32,
    /// Data to write; None for a read of `len` bytes.
    pub data: Option<Vec<u8>>,
    /// Bytes to read when `data` is None.
    pub len: usize,
}

/// Build one frame holding all `requests`, every datagram carrying `index`.
pub fn build_request_frame(
    buf: &mut [u8; MAX_FRAME_LEN],
    index: u8,
    requests: &[Request],
) -> Result<usize, String> {
    let mut b = FrameBuilder::new(&mut buf[..], MASTER_MAC).map_err(|e| e.to_string())?;
    let mut used = 0usize;
    for (i, r) in requests.iter().enumerate() {
        let len = r.data.as_ref().map_or(r.len, |d| d.len());
        b.push(r.cmd, index, r.address, r.data.as_deref(), r.len)
            .map_err(|e| {
                format!(
                    "datagram {i} ({} with {len} bytes) does not fit in one frame \
                 ({used} bytes of datagrams before it, {} bytes per frame): {e}",
                    r.cmd.name(),
                    wire::MAX_PAYLOAD - wire::ECAT_HEADER_LEN,
                )
            })?;
        used += wire::DATAGRAM_HEADER_LEN + len + wire::WKC_LEN;
    }
    if b.is_empty() {
        return Err("a frame needs at least one datagram".into());
    }
    Ok(b.finish())
}

/// Index carried by a frame's first datagram, if the frame is EtherCAT at all.
pub fn frame_index(frame: &[u8]) -> Option<u8> {
    let mut it = wire::datagrams(frame).ok()?;
    match it.next() {
        Some(Ok(d)) => Some(d.index),
        _ => None,
    }
}

/// Does `reply` answer `request`? Same datagrams in the same order with the same command,
/// length and (unless `ignore_index`) index. Addresses are not compared: slaves increment the
/// position of auto-increment datagrams on the way.
pub fn reply_matches(request: &[u8], reply: &[u8], ignore_index: bool) -> bool {
    let (Ok(mut a), Ok(mut b)) = (wire::datagrams(request), wire::datagrams(reply)) else {
        return false;
    };
    loop {
        match (a.next(), b.next()) {
            (None, None) => return true,
            (Some(Ok(x)), Some(Ok(y))) => {
                if x.cmd != y.cmd
                    || x.slot.len != y.slot.len
                    || x.slot.header != y.slot.header
                    || (!ignore_index && x.index != y.index)
                {
                    return false;
                }
            }
            _ => return false,
        }
    }
}

/// The (data, working counter) of every datagram of a matched reply.
pub fn reply_datagrams(reply: &[u8]) -> Vec<(Vec<u8>, u16)> {
    wire::datagrams(reply)
        .map(|it| {
            it.filter_map(Result::ok)
                .map(|d| {
                    (
                        reply[d.slot.data..d.slot.data + d.slot.len].to_vec(),
                        wire::read_wkc(reply, &d.slot),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(cmd: Command, data: Option<Vec<u8>>, len: usize) -> Request {
        Request {
            cmd,
            address: wire::fixed_address(0x1001, 0x130),
            data,
            len,
        }
    }

    #[test]
    fn requests_build_and_match_their_reply() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = build_request_frame(
            &mut buf,
            5,
            &[
                req(Command::Fprd, None, 2),
                req(Command::Fpwr, Some(vec![1, 2, 3]), 0),
            ],
        )
        .unwrap();
        let request = buf[..n].to_vec();
        assert_eq!(frame_index(&request), Some(5));
        let mut reply = request.clone();
        assert!(reply_matches(&request, &reply, false));
        let dgs: Vec<_> = wire::datagrams(&reply)
            .unwrap()
            .map(|d| d.unwrap())
            .collect();
        wire::write_wkc(&mut reply, &dgs[1].slot, 1);
        reply[dgs[0].slot.data] = 8;
        assert_eq!(
            reply_datagrams(&reply),
            vec![(vec![8, 0], 0), (vec![1, 2, 3], 1)]
        );
        // Another index, another command, or a shorter frame do not match.
        let mut other = reply.clone();
        other[dgs[1].slot.header + 1] = 6;
        assert!(!reply_matches(&request, &other, false));
        assert!(reply_matches(&request, &other, true));
        other[dgs[1].slot.header] = Command::Fprw as u8;
        assert!(!reply_matches(&request, &other, true));
        assert!(!reply_matches(&request, &reply[..20], false));
    }

    #[test]
    fn too_many_datagrams_is_a_clear_error() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let many: Vec<_> = (0..3).map(|_| req(Command::Fprd, None, 700)).collect();
        let err = build_request_frame(&mut buf, 0, &many).unwrap_err();
        assert!(
            err.contains("datagram 2 (FPRD with 700 bytes) does not fit"),
            "{err}"
        );
        assert!(build_request_frame(&mut buf, 0, &[]).is_err());
    }
}
