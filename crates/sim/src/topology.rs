//! Where each virtual slave is connected, and how a frame walks the tree of ports.
//!
//! The port order is `ether_ros_protocol::topology`'s (0 → 3 → 1 → 2 → 0, ports a chip does
//! not have skipped): the frame visits the slaves depth first in port order, and that visiting
//! order is the auto-increment order. A port without a link is closed: the frame is forwarded
//! internally to the next port at once. Only the pass through the processing unit (after port
//! 0) processes datagrams.
//!
//! The walk is static between topology changes, so it is computed once (`Walk::compute`) and
//! each frame only replays it: which slaves, in which order, at what offset from the frame's
//! arrival at the first slave, and when the frame comes back into each open port (the receive
//! time latches 0x0900..0x090C).

/// The port order (0 → 3 → 1 → 2) and the forwarding ports: the protocol crate's.
pub use ether_ros_protocol::topology::forwarding_ports;

/// One slave as the walk needs it.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    /// Number of ports of the slave's chip.
    pub ports: u8,
    /// One-way delay of the link from the parent's port (or the master) to this slave, with
    /// the parent's forwarding: the frame arrives `delay_ns` after leaving the parent and is
    /// back at the parent `delay_ns` after leaving this slave through port 0.
    pub delay_ns: u64,
    /// Where the slave's port 0 is connected: `(parent, parent's port)`; None for the first
    /// slave (connected to the master).
    pub upstream: Option<(usize, u8)>,
    /// The link into port 0 is down (a pulled cable between this slave and its parent).
    pub link_down: bool,
}

/// The precomputed path of a frame through the tree.
#[derive(Clone, Debug, Default)]
pub struct Walk {
    /// Reachable slaves in the order the frame's processing unit passes visit them (the
    /// auto-increment order).
    pub order: Vec<usize>,
    /// Per slave: ns from the frame leaving the master until it enters the slave's port 0.
    pub arrival: Vec<u64>,
    /// Per slave and port: ns after the arrival at which the frame comes back into that port
    /// (None: closed, nothing attached or the link down, or the slave is unreachable).
    pub port_return: Vec<[Option<u64>; 4]>,
    /// Per slave: bit p set when port p has a link (port 0: the link towards the master).
    pub open_ports: Vec<u8>,
    /// Ns from leaving the master until the frame is back at the master.
    pub round_trip: u64,
}

impl Walk {
    /// The walk through `nodes` (index = order added). `children[k][p]` is the slave on port p
    /// of slave k.
    pub fn compute(nodes: &[Node]) -> Walk {
        let n = nodes.len();
        let mut children = vec![[None; 4]; n];
        for (k, node) in nodes.iter().enumerate() {
            if let Some((parent, port)) = node.upstream {
                children[parent][port as usize] = Some(k);
            }
        }
        let mut w = Walk {
            order: Vec::with_capacity(n),
            arrival: vec![0; n],
            port_return: vec![[None; 4]; n],
            open_ports: vec![0; n],
            round_trip: 0,
        };
        let Some(first) = nodes.iter().position(|s| s.upstream.is_none()) else {
            return w;
        };
        if nodes[first].link_down {
            return w;
        }
        let leaves_first = w.visit(nodes, &children, first, nodes[first].delay_ns);
        w.round_trip = leaves_first + nodes[first].delay_ns;
        w
    }

    /// The frame enters slave `k` at `t`; returns when it leaves through port 0 again.
    fn visit(&mut self, nodes: &[Node], children: &[[Option<usize>; 4]], k: usize, t: u64) -> u64 {
        self.order.push(k);
        self.arrival[k] = t;
        self.open_ports[k] |= 1;
        let mut now = t;
        for port in forwarding_ports(nodes[k].ports) {
            let Some(child) = children[k][port as usize] else {
                continue;
            };
            if nodes[child].link_down {
                continue;
            }
            let d = nodes[child].delay_ns;
            let back = self.visit(nodes, children, child, now + d) + d;
            self.port_return[k][port as usize] = Some(back - t);
            self.open_ports[k] |= 1 << port;
            now = back;
        }
        now
    }
}

/// Check that slave `new` (just added, the last one) is the last the frame visits: the list of
/// slaves must be in the frame's (auto-increment) order. Returns the slave the frame would
/// reach after `new` when it is not.
pub fn listed_out_of_order(nodes: &[Node]) -> Option<usize> {
    let healthy: Vec<Node> = nodes
        .iter()
        .map(|n| Node {
            link_down: false,
            ..*n
        })
        .collect();
    let walk = Walk::compute(&healthy);
    let new = nodes.len() - 1;
    let at = walk.order.iter().position(|&k| k == new)?;
    walk.order.get(at + 1).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(ports: u8, delay_ns: u64, upstream: Option<(usize, u8)>) -> Node {
        Node {
            ports,
            delay_ns,
            upstream,
            link_down: false,
        }
    }

    #[test]
    fn et1100_order_visits_port_3_before_1_and_2() {
        assert_eq!(forwarding_ports(4).collect::<Vec<_>>(), vec![3, 1, 2]);
        assert_eq!(forwarding_ports(3).collect::<Vec<_>>(), vec![1, 2]);
        assert_eq!(forwarding_ports(2).collect::<Vec<_>>(), vec![1]);
    }

    #[test]
    fn line_times_match_the_sum_of_delays() {
        let nodes = [
            node(2, 100, None),
            node(2, 200, Some((0, 1))),
            node(2, 300, Some((1, 1))),
        ];
        let w = Walk::compute(&nodes);
        assert_eq!(w.order, vec![0, 1, 2]);
        assert_eq!(w.arrival, vec![100, 300, 600]);
        assert_eq!(w.port_return[0][1], Some(2 * (200 + 300)));
        assert_eq!(w.port_return[1][1], Some(2 * 300));
        assert_eq!(w.port_return[2][1], None);
        assert_eq!(w.round_trip, 2 * 600);
    }

    #[test]
    fn branches_are_walked_depth_first() {
        // A junction (0) with a slave on port 1 (1) and one on port 2 (2) that has a child (3).
        let nodes = [
            node(3, 10, None),
            node(2, 100, Some((0, 1))),
            node(2, 200, Some((0, 2))),
            node(2, 50, Some((2, 1))),
        ];
        let w = Walk::compute(&nodes);
        assert_eq!(w.order, vec![0, 1, 2, 3]);
        assert_eq!(w.arrival[2], 10 + 200 + 200);
        assert_eq!(w.port_return[0][1], Some(200));
        assert_eq!(w.port_return[0][2], Some(200 + 2 * 200 + 2 * 50));
        assert_eq!(w.open_ports[0], 0b111);
        let mut broken = nodes;
        broken[2].link_down = true;
        let w = Walk::compute(&broken);
        assert_eq!(w.order, vec![0, 1]);
        assert_eq!(w.open_ports[0], 0b011);
        assert_eq!(listed_out_of_order(&nodes[..3]), None);
    }
}
