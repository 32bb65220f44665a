// Command roundtrip is the Go side of tests/tools/test_types_go.py: the Go types of
// `antalate types --lang go` against the Python classes, both ways.
//
// Each line of standard input is "TYPE HEX", a message the Python classes encoded. The command
// decodes it into the Go type, encodes it again and prints "echo TYPE HEX" (the test wants the
// same bytes back). Then it prints "built TYPE HEX" for messages it made itself (the values the
// test expects, field by field), with operator_cmd_t signed as an antalate node signs
// (docs/design.md §10): HMAC-SHA256 keyed with the swarm key ($ANTALATE_SWARM_KEY) over the whole
// encoding, fingerprint included, while the MAC is empty.
//
// It builds in a module whose root holds the generated antalate_lcm/ folder, named as the import
// below says; the standard library is all it needs.
package main

import (
	"bufio"
	"crypto/hmac"
	"crypto/sha256"
	"encoding/hex"
	"fmt"
	"os"
	"strings"

	msgs "antalate.test/types/antalate_lcm/msgs"
)

type message interface {
	Encode() ([]byte, error)
	Decode(data []byte) error
}

func empty(name string) (message, error) {
	switch name {
	case "header_t":
		return &msgs.AntalateLcmMsgsHeaderT{}, nil
	case "operator_cmd_t":
		return &msgs.AntalateLcmMsgsOperatorCmdT{}, nil
	case "arbiter_status_t":
		return &msgs.AntalateLcmMsgsArbiterStatusT{}, nil
	case "payload_t":
		return &msgs.AntalateLcmMsgsPayloadT{}, nil
	}
	return nil, fmt.Errorf("no Go type for %q", name)
}

func echo(name, hexed string) (string, error) {
	data, err := hex.DecodeString(hexed)
	if err != nil {
		return "", err
	}
	msg, err := empty(name)
	if err != nil {
		return "", err
	}
	if err = msg.Decode(data); err != nil {
		return "", fmt.Errorf("decoding %s: %w", name, err)
	}
	again, err := msg.Encode()
	if err != nil {
		return "", fmt.Errorf("encoding %s: %w", name, err)
	}
	return hex.EncodeToString(again), nil
}

// signedCommand is what a Go node sends to land an agent: MacLen is left to Encode (which sets
// every length field from its slice), then the MAC is computed over the unsigned bytes.
func signedCommand(key string) (message, error) {
	cmd := &msgs.AntalateLcmMsgsOperatorCmdT{
		Header: msgs.AntalateLcmMsgsHeaderT{
			Utime: 1700000000123456,
			Agent: "go-node",
			Seq:   7,
		},
		Command:  msgs.AntalateLcmMsgsOperatorCmdT_LAND,
		Target:   "alpha",
		Altitude: 12.5,
	}
	unsigned, err := cmd.Encode()
	if err != nil {
		return nil, err
	}
	mac := hmac.New(sha256.New, []byte(key))
	mac.Write(unsigned)
	cmd.Header.Mac = mac.Sum(nil)
	return cmd, nil
}

func built(key string) ([][2]string, error) {
	cmd, err := signedCommand(key)
	if err != nil {
		return nil, err
	}
	all := []struct {
		name string
		msg  message
	}{
		{"operator_cmd_t", cmd},
		{"arbiter_status_t", &msgs.AntalateLcmMsgsArbiterStatusT{
			Header:  msgs.AntalateLcmMsgsHeaderT{Utime: 42, Agent: "bravo", Seq: -3},
			Arbiter: "bma",
			State:   "MISSION",
			Active:  []string{"dovrat_swarm", "avoid"},
			Failed:  []string{"video: no camera"},
		}},
		{"payload_t", &msgs.AntalateLcmMsgsPayloadT{
			Header:      msgs.AntalateLcmMsgsHeaderT{Utime: 1, Agent: "station", Seq: 2},
			ContentType: "application/json",
			Data:        []byte(`{"k": 1}`),
		}},
	}
	out := make([][2]string, 0, len(all))
	for _, m := range all {
		data, err := m.msg.Encode()
		if err != nil {
			return nil, fmt.Errorf("encoding %s: %w", m.name, err)
		}
		out = append(out, [2]string{m.name, hex.EncodeToString(data)})
	}
	return out, nil
}

func run() error {
	lines := bufio.NewScanner(os.Stdin)
	lines.Buffer(make([]byte, 1<<20), 1<<20)
	for lines.Scan() {
		fields := strings.Fields(lines.Text())
		if len(fields) == 0 {
			continue
		}
		if len(fields) != 2 {
			return fmt.Errorf("want \"TYPE HEX\", got %q", lines.Text())
		}
		again, err := echo(fields[0], fields[1])
		if err != nil {
			return err
		}
		fmt.Printf("echo %s %s\n", fields[0], again)
	}
	if err := lines.Err(); err != nil {
		return err
	}
	messages, err := built(os.Getenv("ANTALATE_SWARM_KEY"))
	if err != nil {
		return err
	}
	for _, m := range messages {
		fmt.Printf("built %s %s\n", m[0], m[1])
	}
	return nil
}

func main() {
	if err := run(); err != nil {
		fmt.Fprintln(os.Stderr, "roundtrip:", err)
		os.Exit(1)
	}
}
