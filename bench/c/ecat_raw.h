/* Shared helpers of the benchmark C tools: a raw AF_PACKET socket bound to one interface and
 * the EtherCAT frame layout (ETG.1000.4: Ethernet type 0x88A4, a 2-byte EtherCAT header with an
 * 11-bit length and type 1, then datagrams of a 10-byte header, data and a 2-byte working
 * counter). */
#ifndef ECAT_RAW_H
#define ECAT_RAW_H

#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <linux/if_ether.h>
#include <linux/if_packet.h>
#include <net/if.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define ETHERTYPE_ECAT 0x88A4
#define ETH_HDR 14
#define ECAT_HDR 2
#define DG_HDR 10
#define DG_WKC 2

static inline uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

/* A raw socket on `ifname` receiving only EtherCAT frames; exits with a message on failure. */
static inline int open_raw(const char *ifname, int *ifindex_out) {
    int fd = socket(AF_PACKET, SOCK_RAW, htons(ETHERTYPE_ECAT));
    if (fd < 0) {
        perror("socket(AF_PACKET)");
        exit(2);
    }
    unsigned idx = if_nametoindex(ifname);
    if (idx == 0) {
        fprintf(stderr, "no such interface: %s\n", ifname);
        exit(2);
    }
    struct sockaddr_ll sll;
    memset(&sll, 0, sizeof sll);
    sll.sll_family = AF_PACKET;
    sll.sll_protocol = htons(ETHERTYPE_ECAT);
    sll.sll_ifindex = (int)idx;
    if (bind(fd, (struct sockaddr *)&sll, sizeof sll) < 0) {
        perror("bind");
        exit(2);
    }
    /* Never block the sender on a full queue silently; keep the default buffers. */
    *ifindex_out = (int)idx;
    return fd;
}

/* Optional real-time setup: SCHED_FIFO priority (0 = leave), CPU pin (-1 = leave), mlockall. */
static inline void rt_setup(int priority, int cpu) {
    if (cpu >= 0) {
        cpu_set_t set;
        CPU_ZERO(&set);
        CPU_SET(cpu, &set);
        if (sched_setaffinity(0, sizeof set, &set) != 0) perror("sched_setaffinity");
    }
    if (priority > 0) {
        struct sched_param sp = {.sched_priority = priority};
        if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0) perror("sched_setscheduler");
        if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) perror("mlockall");
    }
}

/* Walk the datagrams of an EtherCAT frame of `len` bytes; call `fn` for each one with its header
 * and data length. Returns the number of datagrams, or -1 when the frame is malformed. */
typedef void (*datagram_fn)(uint8_t *dg, unsigned data_len, void *ctx);

static inline int for_each_datagram(uint8_t *frame, size_t len, datagram_fn fn, void *ctx) {
    if (len < ETH_HDR + ECAT_HDR) return -1;
    if (frame[12] != 0x88 || frame[13] != 0xA4) return -1;
    unsigned ecat_len = (unsigned)(frame[14] | (frame[15] << 8)) & 0x7FF;
    size_t pos = ETH_HDR + ECAT_HDR;
    size_t end = pos + ecat_len;
    if (end > len) return -1;
    int n = 0;
    for (;;) {
        if (pos + DG_HDR + DG_WKC > end) return -1;
        uint8_t *dg = frame + pos;
        unsigned lenflags = (unsigned)(dg[6] | (dg[7] << 8));
        unsigned data_len = lenflags & 0x7FF;
        if (pos + DG_HDR + data_len + DG_WKC > end) return -1;
        if (fn) fn(dg, data_len, ctx);
        n++;
        pos += DG_HDR + data_len + DG_WKC;
        if (!(lenflags & 0x8000)) break; /* no "more datagrams" flag */
    }
    return n;
}

#endif
