//! The master's engine: owns the link, serves acyclic datagrams for the Python bring-up, and
//! runs the cyclic real-time thread in OP. See docs/architecture.md.
