/* Minimal EtherCAT echo responder: the same-run baseline for the simulator's round trip.
 *
 * It does the least a slave line must do to answer a frame: receive an EtherCAT frame on a raw
 * socket, add 1 to the working counter of every datagram, set the "passed through a slave" bit
 * (0x02) of the first source-MAC byte, and send the frame back out of the same interface. No
 * registers, no process data: whatever the simulator adds on top of this is its own cost.
 *
 * usage: echo IFACE [-p fifo_priority] [-c cpu] [-n max_frames]
 * Prints "ready" once the socket is bound, and "echoed N" on exit (SIGTERM/SIGINT or -n). */
#include "ecat_raw.h"

#include <signal.h>

static volatile sig_atomic_t stop;

static void on_signal(int sig) {
    (void)sig;
    stop = 1;
}

static void bump_wkc(uint8_t *dg, unsigned data_len, void *ctx) {
    (void)ctx;
    uint8_t *wkc = dg + DG_HDR + data_len;
    unsigned v = (unsigned)(wkc[0] | (wkc[1] << 8)) + 1;
    wkc[0] = (uint8_t)v;
    wkc[1] = (uint8_t)(v >> 8);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s IFACE [-p prio] [-c cpu] [-n max_frames]\n", argv[0]);
        return 2;
    }
    const char *ifname = argv[1];
    int prio = 0, cpu = -1;
    long max_frames = -1;
    for (int i = 2; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "-p")) prio = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-c")) cpu = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-n")) max_frames = atol(argv[i + 1]);
        else {
            fprintf(stderr, "unknown option %s\n", argv[i]);
            return 2;
        }
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal; /* no SA_RESTART: recvfrom returns EINTR and we stop */
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);

    int ifindex;
    int fd = open_raw(ifname, &ifindex);
    rt_setup(prio, cpu);
    printf("ready\n");
    fflush(stdout);

    uint8_t buf[2048];
    long echoed = 0;
    struct sockaddr_ll from;
    while (!stop && (max_frames < 0 || echoed < max_frames)) {
        socklen_t fl = sizeof from;
        ssize_t n = recvfrom(fd, buf, sizeof buf, 0, (struct sockaddr *)&from, &fl);
        if (n < 0) {
            if (errno == EINTR) continue;
            perror("recvfrom");
            return 1;
        }
        /* Our own transmissions come back on the socket as PACKET_OUTGOING; skip them, and skip
         * frames already answered by a slave (bit set). */
        if (from.sll_pkttype == PACKET_OUTGOING || (buf[6] & 0x02)) continue;
        if (for_each_datagram(buf, (size_t)n, bump_wkc, NULL) < 0) continue;
        buf[6] |= 0x02;
        if (send(fd, buf, (size_t)n, 0) < 0) {
            if (errno == EINTR) continue;
            perror("send");
            return 1;
        }
        echoed++;
    }
    printf("echoed %ld\n", echoed);
    return 0;
}
