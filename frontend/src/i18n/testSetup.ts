// Unit tests speak British English, whatever the test browser's languages: the tests of
// other languages choose theirs.
import { beforeEach } from "vitest";
import { useLocale } from "./index";

beforeEach(() => useLocale("en-GB"));
