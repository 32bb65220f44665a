/*
 * A node in C: watch an agent's Mission Control and tell it to take off.
 *
 * Built from the C types that `antalate types --lang c` writes and any liblcm (Debian's
 * liblcm-dev, or the one in the lcm Python wheel); signing uses OpenSSL's libcrypto:
 *
 *   antalate types --lang c --out types
 *   cc -o takeoff_node takeoff_node.c types/antalate_lcm_msgs_*.c -Itypes $(pkg-config --cflags --libs lcm) -lcrypto
 *   ANTALATE_SWARM_KEY=... ./takeoff_node 'udpm://239.255.76.67:7667?ttl=0' alpha 4.0
 *
 * It waits for alpha/MC_STATE in STANDBY, sends operator_cmd_t TAKEOFF on alpha/OPERATOR_CMD (signed
 * when ANTALATE_SWARM_KEY is set: HMAC-SHA256 over the encoded message with header.mac empty, as
 * docs/design.md section 10 says), resends it with a fresh utime every second until the MC
 * acknowledges it (last_command_seq) or ACK_TIMEOUT_S pass (default 30), then waits for MISSION.
 * One JSON line per event on stdout; exit 0 when the agent is in MISSION, 1 on a timeout, 2 on a
 * usage or set-up error.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>
#include <time.h>

#include <lcm/lcm.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include "antalate_lcm_msgs_mc_state_t.h"
#include "antalate_lcm_msgs_operator_cmd_t.h"

#define SENDER "c-node"
#define COMMAND_SEQ 1

typedef struct {
    int have_state;
    int8_t state;
    int32_t last_command_seq;
    int acked_printed;
} watch_t;

static int64_t now_us(void)
{
    struct timeval tv;
    gettimeofday(&tv, NULL);
    return (int64_t) tv.tv_sec * 1000000 + tv.tv_usec;
}

static void on_mc_state(const lcm_recv_buf_t *rbuf, const char *channel,
                        const antalate_lcm_msgs_mc_state_t *msg, void *user)
{
    (void) rbuf;
    watch_t *w = (watch_t *) user;
    if (!w->have_state || w->state != msg->state || w->last_command_seq != msg->last_command_seq) {
        printf("{\"event\": \"mc_state\", \"channel\": \"%s\", \"from\": \"%s\", \"state\": %d, "
               "\"last_command_seq\": %" PRId32 ", \"signed\": %s}\n",
               channel, msg->header.agent, msg->state, msg->last_command_seq,
               msg->header.mac_len > 0 ? "true" : "false");
        fflush(stdout);
    }
    w->have_state = 1;
    w->state = msg->state;
    w->last_command_seq = msg->last_command_seq;
}

/* Publish the command, signed with `key` when it is not NULL. */
static int send_takeoff(lcm_t *lcm, const char *channel, const char *target, float altitude,
                        const char *key)
{
    uint8_t mac[EVP_MAX_MD_SIZE];
    unsigned int mac_len = 0;
    antalate_lcm_msgs_operator_cmd_t cmd;
    memset(&cmd, 0, sizeof cmd);
    cmd.header.utime = now_us();
    cmd.header.agent = (char *) SENDER;
    cmd.header.seq = COMMAND_SEQ;
    cmd.header.mac_len = 0;
    cmd.header.mac = NULL;
    cmd.command = ANTALATE_LCM_MSGS_OPERATOR_CMD_T_TAKEOFF;
    cmd.target = (char *) target;
    cmd.altitude = altitude;

    if (key != NULL) {
        /* The MAC covers the whole encoded message (fingerprint included) with mac_len = 0. */
        int size = antalate_lcm_msgs_operator_cmd_t_encoded_size(&cmd);
        uint8_t *buf = malloc((size_t) size);
        if (buf == NULL || antalate_lcm_msgs_operator_cmd_t_encode(buf, 0, size, &cmd) != size) {
            free(buf);
            fprintf(stderr, "takeoff_node: cannot encode the command\n");
            return -1;
        }
        if (HMAC(EVP_sha256(), key, (int) strlen(key), buf, (size_t) size, mac, &mac_len) == NULL) {
            free(buf);
            fprintf(stderr, "takeoff_node: HMAC-SHA256 failed\n");
            return -1;
        }
        free(buf);
        cmd.header.mac_len = (int16_t) mac_len;
        cmd.header.mac = mac;
    }
    int rc = antalate_lcm_msgs_operator_cmd_t_publish(lcm, channel, &cmd);
    printf("{\"event\": \"sent\", \"channel\": \"%s\", \"command\": \"TAKEOFF\", \"seq\": %d, "
           "\"utime\": %" PRId64 ", \"mac_len\": %u, \"rc\": %d}\n",
           channel, COMMAND_SEQ, cmd.header.utime, mac_len, rc);
    fflush(stdout);
    return rc;
}

/* Handle messages until `done(w)` or `seconds` pass; resend the command every second if asked. */
static int wait_until(lcm_t *lcm, watch_t *w, int (*done)(const watch_t *), double seconds,
                      const char *cmd_channel, const char *target, float altitude, const char *key)
{
    int64_t deadline = now_us() + (int64_t) (seconds * 1e6);
    int64_t next_send = 0;
    while (!done(w)) {
        int64_t now = now_us();
        if (now > deadline)
            return 0;
        if (cmd_channel != NULL && now >= next_send) {
            if (send_takeoff(lcm, cmd_channel, target, altitude, key) != 0)
                return 0;
            next_send = now + 1000000;
        }
        if (lcm_handle_timeout(lcm, 100) < 0)
            return 0;
    }
    return 1;
}

static int in_standby(const watch_t *w)
{
    return w->have_state && w->state == ANTALATE_LCM_MSGS_MC_STATE_T_STANDBY;
}

static int acknowledged(const watch_t *w)
{
    return w->have_state && w->last_command_seq == COMMAND_SEQ;
}

static int in_mission(const watch_t *w)
{
    return w->have_state && w->state == ANTALATE_LCM_MSGS_MC_STATE_T_MISSION;
}

int main(int argc, char **argv)
{
    if (argc != 4 && argc != 5) {
        fprintf(stderr, "usage: %s LCM_URL AGENT ALTITUDE_M [ACK_TIMEOUT_S]  (env ANTALATE_SWARM_KEY: sign)\n",
                argv[0]);
        return 2;
    }
    const char *url = argv[1], *agent = argv[2];
    float altitude = strtof(argv[3], NULL);
    double ack_timeout = argc == 5 ? strtod(argv[4], NULL) : 30.0;
    const char *key = getenv("ANTALATE_SWARM_KEY");
    if (key != NULL && key[0] == '\0')
        key = NULL;

    char state_channel[256], cmd_channel[256];
    snprintf(state_channel, sizeof state_channel, "%s/MC_STATE", agent);
    snprintf(cmd_channel, sizeof cmd_channel, "%s/OPERATOR_CMD", agent);

    lcm_t *lcm = lcm_create(url);
    if (lcm == NULL) {
        fprintf(stderr, "takeoff_node: cannot create LCM on %s (is there a multicast route?)\n", url);
        return 2;
    }
    watch_t w;
    memset(&w, 0, sizeof w);
    antalate_lcm_msgs_mc_state_t_subscribe(lcm, state_channel, on_mc_state, &w);

    int ok = wait_until(lcm, &w, in_standby, 30.0, NULL, agent, altitude, key) &&
             wait_until(lcm, &w, acknowledged, ack_timeout, cmd_channel, agent, altitude, key) &&
             wait_until(lcm, &w, in_mission, 30.0, NULL, agent, altitude, key);
    printf("{\"event\": \"%s\", \"state\": %d, \"last_command_seq\": %" PRId32 "}\n",
           ok ? "done" : "timeout", w.have_state ? w.state : -1, w.last_command_seq);
    lcm_destroy(lcm);
    return ok ? 0 : 1;
}
