// Command hostile is the Go side of tests/tools/test_types_go.py's hostile-datagram test: what a Go node
// on a shared network can be sent, fed to the Decode of every type of `antalate types --lang go`
// (and of demo/maps, a multi-dimensional type the test generates beside them). Decode must return
// an error, never panic, and never allocate what a forged length claims.
//
// For each type it fills a message (every string and array non-empty, through reflection, so a
// new field is covered without editing this file), checks that it and one with every variable
// array empty decode and re-encode to the same bytes and value, then decodes
//   - every proper prefix of that encoding (each must be an error),
//   - the encoding with each 1, 2 and 4 byte window overwritten by a huge and by negative values
//     (so every string and array length field, wherever it is, is set to each),
//   - seeded random byte strings after the right fingerprint, and random mutations of the encoding.
//
// It prints one JSON line per type: the valid encoding (the test has Python decode it), how many
// decodes ran, the first word of each error and how often, the panics (with the input) and the
// bytes allocated over the hostile decodes. It exits 1 if anything panicked.
//
// It builds in a module whose root holds the generated antalate_lcm/ and demo/ folders, named as
// the imports below say; the standard library is all it needs.
package main

import (
	"encoding/binary"
	"encoding/hex"
	"encoding/json"
	"errors"
	"fmt"
	"math/rand"
	"os"
	"reflect"
	"runtime"
	"sort"
	"strings"

	msgs "antalate.test/types/antalate_lcm/msgs"
	maps "antalate.test/types/demo/maps"
)

type message interface {
	Encode() ([]byte, error)
	Decode(data []byte) error
}

// types maps each .lcm type name to a constructor of its empty Go value.
var types = map[string]func() message{
	"arbiter_status_t": func() message { return &msgs.AntalateLcmMsgsArbiterStatusT{} },
	"behavior_state_t": func() message { return &msgs.AntalateLcmMsgsBehaviorStateT{} },
	"direction_cmd_t":  func() message { return &msgs.AntalateLcmMsgsDirectionCmdT{} },
	"header_t":         func() message { return &msgs.AntalateLcmMsgsHeaderT{} },
	"hlc_error_t":      func() message { return &msgs.AntalateLcmMsgsHlcErrorT{} },
	"hlc_state_t":      func() message { return &msgs.AntalateLcmMsgsHlcStateT{} },
	"mc_state_t":       func() message { return &msgs.AntalateLcmMsgsMcStateT{} },
	"operator_cmd_t":   func() message { return &msgs.AntalateLcmMsgsOperatorCmdT{} },
	"payload_t":        func() message { return &msgs.AntalateLcmMsgsPayloadT{} },
	"peer_detection_t": func() message { return &msgs.AntalateLcmMsgsPeerDetectionT{} },
	"peer_scan_t":      func() message { return &msgs.AntalateLcmMsgsPeerScanT{} },
	"telemetry_t":      func() message { return &msgs.AntalateLcmMsgsTelemetryT{} },
	"velocity_cmd_t":   func() message { return &msgs.AntalateLcmMsgsVelocityCmdT{} },
	"demo.maps.cell_t": func() message { return &maps.DemoMapsCellT{} },
	"demo.maps.grid_t": func() message { return &maps.DemoMapsGridT{} },
}

// fill gives every field of v a value: numbers from seed, strings of a few bytes, slices of n
// elements. Length fields get a number too; Encode sets them from their slices, but for a length
// whose first array is inside an empty one (grid_t.n_cells, when rows is 0): with n = 0 every
// number is 0, so that one is right.
func fill(v reflect.Value, seed *int, n int) {
	if n > 0 {
		*seed++
	}
	switch v.Kind() {
	case reflect.Bool:
		v.SetBool(*seed%2 == 0)
	case reflect.Int8, reflect.Int16, reflect.Int32, reflect.Int64:
		v.SetInt(int64(*seed))
	case reflect.Uint8:
		v.SetUint(uint64(*seed))
	case reflect.Float32, reflect.Float64:
		v.SetFloat(float64(*seed) + 0.5)
	case reflect.String:
		v.SetString(fmt.Sprintf("s%d", *seed))
	case reflect.Slice:
		v.Set(reflect.MakeSlice(v.Type(), n, n))
		fallthrough
	case reflect.Array:
		for i := 0; i < v.Len(); i++ {
			fill(v.Index(i), seed, n)
		}
	case reflect.Struct:
		for i := 0; i < v.NumField(); i++ {
			fill(v.Field(i), seed, n)
		}
	default:
		panic(fmt.Sprintf("fill: no value for %v", v.Type()))
	}
}

type report struct {
	Type      string         `json:"type"`
	Valid     string         `json:"valid"`
	Decodes   int            `json:"decodes"`
	Errors    map[string]int `json:"errors"`
	Panics    []string       `json:"panics"`
	Allocated uint64         `json:"allocated"`
}

var errPanicked = errors.New("panicked")

// decode runs one hostile decode; a panic is recorded and returned as errPanicked, not raised.
func (r *report) decode(name, what string, data []byte) (err error) {
	r.Decodes++
	defer func() {
		if p := recover(); p != nil {
			if len(r.Panics) < 5 {
				r.Panics = append(r.Panics, fmt.Sprintf("%s: %v (input %s)", what, p, hex.EncodeToString(data)))
			}
			err = errPanicked
		}
	}()
	err = types[name]().Decode(data)
	if err != nil {
		kind := err.Error()
		if i := strings.Index(kind, " ("); i >= 0 {
			kind = kind[:i]
		}
		r.Errors[kind]++
	}
	return err
}

// valid is the encoding of a message of name with every variable array n long, which must decode
// and encode again to the same bytes and the same value.
func valid(name string, n int) ([]byte, error) {
	msg := types[name]()
	seed := 0
	fill(reflect.ValueOf(msg).Elem(), &seed, n)
	data, err := msg.Encode()
	if err != nil {
		return nil, err
	}
	again := types[name]()
	if err = again.Decode(data); err != nil {
		return nil, fmt.Errorf("the valid message does not decode: %w", err)
	}
	echo, err := again.Encode()
	if err != nil {
		return nil, err
	}
	if !reflect.DeepEqual(msg, again) || hex.EncodeToString(echo) != hex.EncodeToString(data) {
		return nil, fmt.Errorf("the valid message does not round-trip")
	}
	return data, nil
}

// forged values for a length field: huge, the largest of its width, negative in every width
var windows = map[int][]uint64{
	1: {0x7f, 0x80, 0xff},
	2: {0x7fff, 0x8000, 0xffff},
	4: {0x7fffffff, 0x80000000, 0xffffffff, 0x00010000},
}

func hostile(name string, data []byte, rng *rand.Rand) (*report, error) {
	r := &report{Type: name, Valid: hex.EncodeToString(data), Errors: map[string]int{}, Panics: []string{}}
	var before, after runtime.MemStats
	runtime.ReadMemStats(&before)
	for n := 0; n < len(data); n++ {
		if r.decode(name, fmt.Sprintf("prefix %d", n), data[:n]) == nil {
			return nil, fmt.Errorf("%s: the first %d of %d bytes decoded without error", name, n, len(data))
		}
	}
	forged := make([]byte, len(data))
	for width, values := range windows {
		for at := 8; at+width <= len(data); at++ {
			for _, v := range values {
				copy(forged, data)
				switch width {
				case 1:
					forged[at] = byte(v)
				case 2:
					binary.BigEndian.PutUint16(forged[at:], uint16(v))
				case 4:
					binary.BigEndian.PutUint32(forged[at:], uint32(v))
				}
				r.decode(name, fmt.Sprintf("%d bytes at %d set to %#x", width, at, v), forged)
			}
		}
	}
	for i := 0; i < 2000; i++ {
		noise := make([]byte, 8+rng.Intn(2*len(data)))
		copy(noise, data[:8])
		rng.Read(noise[8:])
		r.decode(name, "random bytes", noise)

		copy(forged, data)
		for k := rng.Intn(4); k >= 0; k-- {
			forged[8+rng.Intn(len(data)-8)] = byte(rng.Intn(256))
		}
		r.decode(name, "random mutation", forged[:8+rng.Intn(len(data)-7)])
	}
	runtime.ReadMemStats(&after)
	r.Allocated = after.TotalAlloc - before.TotalAlloc
	return r, nil
}

func run() (bool, error) {
	rng := rand.New(rand.NewSource(20261123))
	names := make([]string, 0, len(types))
	for name := range types {
		names = append(names, name)
	}
	sort.Strings(names)
	ok := true
	out := json.NewEncoder(os.Stdout)
	for _, name := range names {
		// a message with every variable array empty is valid too: the checks must let it through
		if _, err := valid(name, 0); err != nil {
			return false, fmt.Errorf("%s with empty arrays: %w", name, err)
		}
		data, err := valid(name, 2)
		if err != nil {
			return false, fmt.Errorf("%s: %w", name, err)
		}
		r, err := hostile(name, data, rng)
		if err != nil {
			return false, err
		}
		ok = ok && len(r.Panics) == 0
		if err = out.Encode(r); err != nil {
			return false, err
		}
	}
	return ok, nil
}

func main() {
	ok, err := run()
	if err != nil {
		fmt.Fprintln(os.Stderr, "hostile:", err)
		os.Exit(2)
	}
	if !ok {
		fmt.Fprintln(os.Stderr, "hostile: a decode panicked")
		os.Exit(1)
	}
}
