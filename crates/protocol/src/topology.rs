//! The order in which an ESC passes a frame from port to port.
//!
//! Facts (Beckhoff ESC datasheet section I, "Frame processing order" and "Loop control"): a
//! frame entering port 0 passes the EtherCAT processing unit, then leaves through the next port
//! in the order 0 → 3 → 1 → 2 → 0 (ports a chip does not have are skipped: ET1200 0 → 1 → 2,
//! two-port chips 0 → 1). A port without a link is closed and the frame goes on to the next
//! port internally. What comes back into a port leaves through the next one, finally through
//! port 0 back towards the master. So the frame visits the slaves depth first in port order,
//! and that visiting order is the auto-increment order.

/// Order in which an ESC passes a frame from port to port (after port 0's processing unit).
pub const PORT_ORDER: [u8; 4] = [0, 3, 1, 2];

/// Ports after port 0, in the order the frame leaves through them, on a chip with `ports`
/// ports (0..ports).
pub fn forwarding_ports(ports: u8) -> impl Iterator<Item = u8> {
    PORT_ORDER[1..].iter().copied().filter(move |&p| p < ports)
}

/// The ports after port 0 in `mask` (bit p = port p), in the order the frame uses them.
pub fn forwarding_ports_of_mask(mask: u8) -> impl Iterator<Item = u8> {
    PORT_ORDER[1..]
        .iter()
        .copied()
        .filter(move |&p| mask & (1 << p) != 0)
}

/// Rank of `port` in the forwarding order (port 0 first; `usize::MAX` for no port).
pub fn order_rank(port: u8) -> usize {
    PORT_ORDER
        .iter()
        .position(|&p| p == port)
        .unwrap_or(usize::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_order() {
        assert_eq!(forwarding_ports(4).collect::<Vec<_>>(), [3, 1, 2]);
        assert_eq!(forwarding_ports(3).collect::<Vec<_>>(), [1, 2]);
        assert_eq!(
            forwarding_ports_of_mask(0b1110).collect::<Vec<_>>(),
            [3, 1, 2]
        );
        assert_eq!(order_rank(3), 1);
        assert_eq!(order_rank(7), usize::MAX);
    }
}
