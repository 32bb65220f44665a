import java.io.ByteArrayOutputStream;
import java.io.DataOutputStream;
import java.lang.reflect.Array;
import java.lang.reflect.Constructor;
import java.lang.reflect.Field;
import java.lang.reflect.Modifier;
import java.nio.file.Files;
import java.nio.file.Path;
import java.nio.file.Paths;

import lcm.lcm.LCMEncodable;

/**
 * The Java side of tests/tools/test_spy.py: decodes what Python encoded with the lcm-gen Java classes.
 *
 * <pre>
 *   java DecodeCheck decode DIR TYPE...   for each TYPE reads DIR/TYPE.bin, decodes it with
 *                                         new antalate_lcm.msgs.TYPE(byte[]), prints one JSON line
 *                                         {"type": TYPE, "fields": {...}} and writes the Java
 *                                         re-encoding to DIR/TYPE.java.bin
 *   java DecodeCheck spytypes TYPE=FP...  asks lcm-spy's own type database (lcm.spy.LCMTypeDatabase,
 *                                         which scans the classpath as lcm-spy does) which class it
 *                                         maps each fingerprint (16 hex digits) to; prints TYPE=CLASS
 * </pre>
 *
 * Fields are read by reflection so the program needs no change when a .lcm file gains a field.
 */
public final class DecodeCheck {
    private static final String PACKAGE = "antalate_lcm.msgs.";

    public static void main(String[] args) throws Exception {
        if (args.length >= 2 && args[0].equals("decode")) {
            Path dir = Paths.get(args[1]);
            for (int i = 2; i < args.length; i++) {
                decode(dir, args[i]);
            }
        } else if (args.length >= 1 && args[0].equals("spytypes")) {
            lcm.spy.LCMTypeDatabase db = new lcm.spy.LCMTypeDatabase();
            for (int i = 1; i < args.length; i++) {
                String[] kv = args[i].split("=", 2);
                Class<?> cls = db.getClassByFingerprint(Long.parseUnsignedLong(kv[1], 16));
                System.out.println(kv[0] + "=" + (cls == null ? "" : cls.getName()));
            }
        } else {
            System.err.println("usage: DecodeCheck decode DIR TYPE... | DecodeCheck spytypes TYPE=FINGERPRINT...");
            System.exit(64);
        }
    }

    private static void decode(Path dir, String type) throws Exception {
        byte[] data = Files.readAllBytes(dir.resolve(type + ".bin"));
        Constructor<?> ctor = Class.forName(PACKAGE + type).getConstructor(byte[].class);
        Object msg = ctor.newInstance((Object) data);

        ByteArrayOutputStream buf = new ByteArrayOutputStream();
        ((LCMEncodable) msg).encode(new DataOutputStream(buf));
        Files.write(dir.resolve(type + ".java.bin"), buf.toByteArray());

        StringBuilder out = new StringBuilder();
        out.append("{\"type\": ").append(quote(type)).append(", \"fields\": ");
        appendValue(out, msg);
        out.append('}');
        System.out.println(out);
    }

    private static void appendValue(StringBuilder out, Object value) throws IllegalAccessException {
        if (value == null) {
            out.append("null");
        } else if (value instanceof String) {
            out.append(quote((String) value));
        } else if (value instanceof byte[]) {
            // byte arrays as hex, the way tests/children/probe.py shows them
            StringBuilder hex = new StringBuilder();
            for (byte b : (byte[]) value) {
                hex.append(String.format("%02x", b & 0xff));
            }
            out.append(quote(hex.toString()));
        } else if (value.getClass().isArray()) {
            out.append('[');
            for (int i = 0; i < Array.getLength(value); i++) {
                if (i > 0) {
                    out.append(", ");
                }
                appendValue(out, Array.get(value, i));
            }
            out.append(']');
        } else if (value instanceof LCMEncodable) {
            out.append('{');
            boolean first = true;
            for (Field f : value.getClass().getFields()) {
                if (Modifier.isStatic(f.getModifiers())) {
                    continue;
                }
                if (!first) {
                    out.append(", ");
                }
                first = false;
                out.append(quote(f.getName())).append(": ");
                appendValue(out, f.get(value));
            }
            out.append('}');
        } else {
            // Number or Boolean: Float.toString / Double.toString round-trip exactly (NaN, Infinity too)
            out.append(value);
        }
    }

    private static String quote(String s) {
        StringBuilder q = new StringBuilder("\"");
        for (char c : s.toCharArray()) {
            if (c == '"' || c == '\\') {
                q.append('\\').append(c);
            } else if (c < 0x20 || c > 0x7e) {
                q.append(String.format("\\u%04x", (int) c));
            } else {
                q.append(c);
            }
        }
        return q.append('"').toString();
    }
}
