/* EtherCAT round-trip probe and load generator.
 *
 * Sends frames holding one LRW datagram (the shape of a master's cyclic frame) out of IFACE and
 * matches the answers (first source-MAC byte with bit 0x02 set, same datagram index) to record
 * each round trip in nanoseconds. Two modes:
 *   -r 0     ping-pong: the next frame leaves when the previous answer arrived (or timed out);
 *   -r HZ    paced: frames leave on an absolute schedule at HZ, answers are collected in between,
 *            so up to 256 frames may be in flight.
 * Prints one JSON object: counts, achieved rate, and round-trip percentiles.
 *
 * usage: rtt IFACE [-r hz] [-n frames | -d seconds] [-s lrw_bytes] [-t timeout_us] [-w warmup]
 *                  [-p fifo_priority] [-c cpu] [-a logical_address]
 */
#include "ecat_raw.h"

#include <poll.h>
#include <sys/prctl.h>

#define SLOTS 256

static int cmp_u64(const void *a, const void *b) {
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

static uint64_t pct(const uint64_t *v, size_t n, double p) {
    if (n == 0) return 0;
    size_t i = (size_t)(p / 100.0 * (double)(n - 1) + 0.5);
    return v[i < n ? i : n - 1];
}

static size_t build_frame(uint8_t *f, unsigned lrw_bytes, uint32_t logical) {
    memset(f, 0, 1514);
    memset(f, 0xFF, 6);          /* broadcast destination */
    memset(f + 6, 0x01, 6);      /* source 01:01:01:01:01:01; slaves set bit 0x02 of byte 0 */
    f[12] = 0x88;
    f[13] = 0xA4;
    unsigned ecat_len = DG_HDR + lrw_bytes + DG_WKC;
    f[14] = (uint8_t)ecat_len;
    f[15] = (uint8_t)(0x10 | ((ecat_len >> 8) & 0x07)); /* type 1: EtherCAT commands */
    uint8_t *dg = f + ETH_HDR + ECAT_HDR;
    dg[0] = 0x0C;                /* LRW */
    dg[1] = 0;                   /* index, set per frame */
    dg[2] = (uint8_t)logical;
    dg[3] = (uint8_t)(logical >> 8);
    dg[4] = (uint8_t)(logical >> 16);
    dg[5] = (uint8_t)(logical >> 24);
    dg[6] = (uint8_t)lrw_bytes;
    dg[7] = (uint8_t)((lrw_bytes >> 8) & 0x07);
    size_t len = ETH_HDR + ECAT_HDR + ecat_len;
    return len < 60 ? 60 : len;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s IFACE [-r hz] [-n frames|-d s] [-s bytes] [-t us] [-w n] "
                        "[-p prio] [-c cpu] [-a logical] [-l over_us]\n", argv[0]);
        return 2;
    }
    const char *ifname = argv[1];
    double rate = 0, duration = 0;
    long frames = 1000, warmup = 100;
    unsigned lrw_bytes = 240, timeout_us = 100000, over_us = 0;
    int prio = 0, cpu = -1;
    uint32_t logical = 0;
    for (int i = 2; i + 1 < argc; i += 2) {
        const char *o = argv[i], *v = argv[i + 1];
        if (!strcmp(o, "-r")) rate = atof(v);
        else if (!strcmp(o, "-n")) frames = atol(v);
        else if (!strcmp(o, "-d")) duration = atof(v);
        else if (!strcmp(o, "-s")) lrw_bytes = (unsigned)atoi(v);
        else if (!strcmp(o, "-t")) timeout_us = (unsigned)atoi(v);
        else if (!strcmp(o, "-w")) warmup = atol(v);
        else if (!strcmp(o, "-p")) prio = atoi(v);
        else if (!strcmp(o, "-c")) cpu = atoi(v);
        else if (!strcmp(o, "-a")) logical = (uint32_t)strtoul(v, NULL, 0);
        else if (!strcmp(o, "-l")) over_us = (unsigned)atoi(v);
        else {
            fprintf(stderr, "unknown option %s\n", o);
            return 2;
        }
    }
    if (lrw_bytes < 1 || lrw_bytes > 1400) {
        fprintf(stderr, "-s must be 1..1400 bytes\n");
        return 2;
    }
    if (duration > 0 && rate > 0) frames = (long)(duration * rate);
    if (frames <= 0) {
        fprintf(stderr, "nothing to send\n");
        return 2;
    }
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
    int ifindex;
    int fd = open_raw(ifname, &ifindex);
    rt_setup(prio, cpu);

    uint8_t tx[1514], rx[2048];
    size_t tx_len = build_frame(tx, lrw_bytes, logical);
    uint64_t *rtts = calloc((size_t)frames + 1, sizeof *rtts);
    uint64_t sent_at[SLOTS];
    uint8_t in_flight[SLOTS];
    memset(in_flight, 0, sizeof in_flight);
    if (!rtts) return 1;
    long sent = 0, answered = 0, recorded = 0, late = 0, unmatched = 0;
    const uint64_t period = rate > 0 ? (uint64_t)(1e9 / rate) : 0;
    const uint64_t t0 = now_ns();
    uint64_t next = t0;
    const long total = frames + warmup;

    while (1) {
        uint64_t now = now_ns();
        int may_send = sent < total &&
                       (rate > 0 ? now >= next : (sent == answered || now - sent_at[(sent - 1) & 0xFF] > timeout_us * 1000ull));
        if (may_send) {
            if (rate <= 0 && sent > answered) in_flight[(sent - 1) & 0xFF] = 0; /* timed out */
            unsigned slot = (unsigned)(sent & 0xFF);
            tx[ETH_HDR + ECAT_HDR + 1] = (uint8_t)slot;
            sent_at[slot] = now_ns();
            in_flight[slot] = 1;
            if (send(fd, tx, tx_len, 0) < 0 && errno != EINTR) {
                perror("send");
                return 1;
            }
            sent++;
            if (rate > 0) {
                next += period;
                /* Behind by more than a few periods (a scheduling stall): skip, don't burst. */
                uint64_t after = now_ns();
                if (after > next + 4 * period) {
                    late += (long)((after - next) / period);
                    next = after + period;
                }
            }
            continue;
        }
        if (sent >= total &&
            (sent == answered || now - sent_at[(sent - 1) & 0xFF] > timeout_us * 1000ull))
            break;
        /* Wait for an answer until the next send is due (paced) or the timeout (ping-pong). */
        uint64_t wait_ns = rate > 0 ? (next > now ? next - now : 0) : 1000000;
        struct timespec ts = {.tv_sec = (time_t)(wait_ns / 1000000000ull),
                              .tv_nsec = (long)(wait_ns % 1000000000ull)};
        struct pollfd pfd = {.fd = fd, .events = POLLIN};
        int r = ppoll(&pfd, 1, &ts, NULL);
        if (r <= 0) continue;
        for (;;) {
            struct sockaddr_ll from;
            socklen_t fl = sizeof from;
            ssize_t n = recvfrom(fd, rx, sizeof rx, MSG_DONTWAIT, (struct sockaddr *)&from, &fl);
            if (n < 0) break;
            uint64_t t = now_ns();
            if (from.sll_pkttype == PACKET_OUTGOING || !(rx[6] & 0x02) || n < ETH_HDR + ECAT_HDR + DG_HDR)
                continue;
            unsigned slot = rx[ETH_HDR + ECAT_HDR + 1];
            if (!in_flight[slot]) {
                unmatched++;
                continue;
            }
            in_flight[slot] = 0;
            answered++;
            /* The slot's sequence number: the most recent frame sent with this index. */
            long seq = sent - 1 - (long)(((unsigned)(sent - 1) - slot) & 0xFF);
            if (seq >= warmup) rtts[recorded++] = t - sent_at[slot];
        }
    }
    double elapsed = (double)(now_ns() - t0) * 1e-9;
    qsort(rtts, (size_t)recorded, sizeof *rtts, cmp_u64);
    double mean = 0;
    for (long i = 0; i < recorded; i++) mean += (double)rtts[i];
    mean = recorded ? mean / (double)recorded : 0;
    /* Answers slower than over_us: what a master cycling every over_us could not have had in
       time (the sorted tail). */
    long over = 0;
    if (over_us)
        while (over < recorded && rtts[recorded - 1 - over] > (uint64_t)over_us * 1000ull) over++;
    printf("{\"sent\": %ld, \"answered\": %ld, \"lost\": %ld, \"unmatched\": %ld, \"late_sends\": %ld, "
           "\"recorded\": %ld, \"over\": %ld, \"over_us\": %u, \"elapsed_s\": %.6f, \"rate_hz\": %.1f, \"lrw_bytes\": %u, "
           "\"rtt_ns\": {\"min\": %llu, \"p50\": %llu, \"p90\": %llu, \"p99\": %llu, "
           "\"p999\": %llu, \"max\": %llu, \"mean\": %.0f}}\n",
           sent, answered, sent - answered, unmatched, late, recorded, over, over_us, elapsed,
           elapsed > 0 ? (double)sent / elapsed : 0.0, lrw_bytes,
           (unsigned long long)(recorded ? rtts[0] : 0), (unsigned long long)pct(rtts, (size_t)recorded, 50),
           (unsigned long long)pct(rtts, (size_t)recorded, 90), (unsigned long long)pct(rtts, (size_t)recorded, 99),
           (unsigned long long)pct(rtts, (size_t)recorded, 99.9),
           (unsigned long long)(recorded ? rtts[recorded - 1] : 0), mean);
    free(rtts);
    return 0;
}
