-- Wireshark dissector for USS telegrams captured by `ussctl capture -o FILE.pcapng`.
--
-- Load it once:   wireshark -X lua_script:tools/wireshark/uss.lua FILE.pcapng
--                 tshark -X lua_script:tools/wireshark/uss.lua -r FILE.pcapng -V
-- or for good:    copy it into ~/.local/lib/wireshark/plugins/ (Help > About > Folders).
--
-- The file's interface has link type USER0 (147). Each packet is an 8-byte header written by
-- ussctl, then the telegram's bytes as they were on the wire:
--   0 header version (1)   1 direction (0 request, 1 reply)   2 outcome (0 good, else the
--   failure: 1 no response, 2 missing STX, 3 start pause, 4 bad LGE, 5 BCC, 6 residual time,
--   7 wrong length, 8 wrong slave, 9 parity, 10 framing, 11 overrun, 12 echo)
--   3 drive address   4 PKW mode (P2013: 0, 3, 4, 127 = variable)   5 PZD words
--   6 flags (bit 0 truncated, bit 1 the request carries a parameter task)   7 reserved
-- Telegram: STX 0x02, LGE, ADR, PKW words, PZD words (big-endian), BCC = XOR of all before.

local uss = Proto("uss", "USS (Universal Serial Interface)")

local directions = { [0] = "request", [1] = "reply" }
local outcomes = {
  [0] = "good", [1] = "no response", [2] = "missing STX", [3] = "start pause not observed",
  [4] = "bad LGE", [5] = "BCC error", [6] = "residual time exceeded", [7] = "wrong length",
  [8] = "wrong slave answered", [9] = "parity error", [10] = "framing error", [11] = "overrun",
  [12] = "echo mismatch",
}
local request_ids = {
  [0] = "no task", [1] = "request value", [2] = "change value (word)",
  [3] = "change value (dword)", [4] = "request descriptive element", [6] = "request array value",
  [7] = "change array value (word)", [8] = "change array value (dword)",
  [9] = "request number of array elements", [11] = "change array value (dword, EEPROM)",
  [12] = "change array value (word, EEPROM)", [13] = "change value (dword, EEPROM)",
  [14] = "change value (word, EEPROM)",
}
local reply_ids = {
  [0] = "no reply", [1] = "value (word)", [2] = "value (dword)", [3] = "descriptive element",
  [4] = "array value (word)", [5] = "array value (dword)", [6] = "number of array elements",
  [7] = "task cannot be executed", [8] = "no change rights",
}
local stw1_bits = {
  "ON", "no OFF2", "no OFF3", "pulses enabled", "RFG enabled", "RFG start", "setpoint enabled",
  "fault acknowledge", "jog right", "jog left", "control by PLC", "reverse", "bit 12",
  "motor potentiometer up", "motor potentiometer down", "local/remote",
}
local zsw1_bits = {
  "ready to switch on", "ready to run", "operation enabled", "fault", "no OFF2", "no OFF3",
  "switching on inhibited", "warning", "no setpoint deviation", "control requested",
  "maximum frequency reached", "no current limit warning", "no holding brake",
  "no motor overload", "running right", "no inverter overload",
}

local f = uss.fields
f.version = ProtoField.uint8("uss.header.version", "Header version")
f.direction = ProtoField.uint8("uss.direction", "Direction", base.DEC, directions)
f.outcome = ProtoField.uint8("uss.outcome", "Outcome", base.DEC, outcomes)
f.drive = ProtoField.uint8("uss.drive", "Drive")
f.pkw_mode = ProtoField.uint8("uss.pkw_mode", "PKW mode (P2013)")
f.pzd_words = ProtoField.uint8("uss.pzd_words", "PZD words")
f.flags = ProtoField.uint8("uss.flags", "Flags", base.HEX)
f.stx = ProtoField.uint8("uss.stx", "STX", base.HEX)
f.lge = ProtoField.uint8("uss.lge", "LGE")
f.adr = ProtoField.uint8("uss.adr", "ADR", base.HEX)
f.address = ProtoField.uint8("uss.address", "Address", base.DEC, nil, 0x1F)
f.broadcast = ProtoField.bool("uss.broadcast", "Broadcast", 8, nil, 0x20)
f.mirror = ProtoField.bool("uss.mirror", "Mirror", 8, nil, 0x40)
f.special = ProtoField.bool("uss.special", "Special", 8, nil, 0x80)
f.pke = ProtoField.uint16("uss.pkw.pke", "PKE", base.HEX)
f.ak = ProtoField.uint16("uss.pkw.ak", "AK", base.DEC, nil, 0xF000)
f.spm = ProtoField.bool("uss.pkw.spm", "SPM", 16, nil, 0x0800)
f.pnu = ProtoField.uint16("uss.pkw.pnu", "PNU (low part)", base.DEC, nil, 0x07FF)
f.ind = ProtoField.uint16("uss.pkw.ind", "IND", base.HEX)
f.pwe = ProtoField.uint16("uss.pkw.pwe", "PWE", base.HEX)
f.parameter = ProtoField.string("uss.pkw.parameter", "Parameter")
f.stw1 = ProtoField.uint16("uss.pzd.stw1", "STW1", base.HEX)
f.zsw1 = ProtoField.uint16("uss.pzd.zsw1", "ZSW1", base.HEX)
f.hsw = ProtoField.int16("uss.pzd.hsw", "Setpoint (HSW)")
f.hiw = ProtoField.int16("uss.pzd.hiw", "Actual value (HIW)")
f.pzd = ProtoField.uint16("uss.pzd.word", "PZD", base.HEX)
f.bcc = ProtoField.uint8("uss.bcc", "BCC", base.HEX)
f.bcc_ok = ProtoField.bool("uss.bcc.ok", "BCC correct")

-- The PNU a PKE and IND carry: the low part (PKE bits 0..10, below 2000) plus 2000 per page;
-- page bit i sits in IND bit PAGE_BITS[i] (MM4, G110, G120: 15, 12, 13, 14, 10, 11).
local PAGE_BITS = { 15, 12, 13, 14, 10, 11 }
local function pnu_of(pke, ind)
  local page = 0
  for i, b in ipairs(PAGE_BITS) do
    if bit.band(ind, bit.lshift(1, b)) ~= 0 then page = page + bit.lshift(1, i - 1) end
  end
  return bit.band(pke, 0x07FF) + 2000 * page
end

local function named_bits(word, names)
  local set = {}
  for i = 0, 15 do
    if bit.band(word, bit.lshift(1, i)) ~= 0 then set[#set + 1] = names[i + 1] end
  end
  return table.concat(set, ", ")
end

function uss.dissector(tvb, pinfo, tree)
  if tvb:len() < 8 then return 0 end
  pinfo.cols.protocol = "USS"
  local direction = tvb(1, 1):uint()
  local outcome = tvb(2, 1):uint()
  local drive = tvb(3, 1):uint()
  local pkw_mode = tvb(4, 1):uint()
  local pzd_words = tvb(5, 1):uint()
  local root = tree:add(uss, tvb(), "USS " .. (directions[direction] or "?") .. ", drive " .. drive)
  local hdr = root:add(tvb(0, 8), "Capture header")
  hdr:add(f.version, tvb(0, 1))
  hdr:add(f.direction, tvb(1, 1))
  hdr:add(f.outcome, tvb(2, 1))
  hdr:add(f.drive, tvb(3, 1))
  hdr:add(f.pkw_mode, tvb(4, 1))
  hdr:add(f.pzd_words, tvb(5, 1))
  hdr:add(f.flags, tvb(6, 1))
  local arrow = direction == 0 and "-> " or "<- "
  local info = arrow .. drive
  if outcome ~= 0 then info = info .. " " .. (outcomes[outcome] or ("outcome " .. outcome)) end
  local t = tvb:len() - 8
  if t < 4 then
    pinfo.cols.info = info
    return tvb:len()
  end
  local lge = tvb(9, 1):uint()
  if lge + 2 ~= t then
    root:add(tvb(8), "Bytes that are not one telegram")
    pinfo.cols.info = info
    return tvb:len()
  end
  root:add(f.stx, tvb(8, 1))
  root:add(f.lge, tvb(9, 1))
  local adr = root:add(f.adr, tvb(10, 1))
  adr:add(f.address, tvb(10, 1))
  adr:add(f.broadcast, tvb(10, 1))
  adr:add(f.mirror, tvb(10, 1))
  adr:add(f.special, tvb(10, 1))
  local words = (lge - 2) / 2
  local pkw = words - pzd_words
  if pkw < 0 then pkw = 0 end
  local at = 11
  if pkw >= 3 then
    local p = root:add(tvb(at, pkw * 2), "PKW")
    local pke = tvb(at, 2):uint()
    local ind = tvb(at + 2, 2):uint()
    local pkeitem = p:add(f.pke, tvb(at, 2))
    pkeitem:add(f.ak, tvb(at, 2))
    pkeitem:add(f.spm, tvb(at, 2))
    pkeitem:add(f.pnu, tvb(at, 2))
    p:add(f.ind, tvb(at + 2, 2))
    for i = 2, pkw - 1 do p:add(f.pwe, tvb(at + 2 * i, 2)) end
    local ak = bit.rshift(pke, 12)
    local pnu = pnu_of(pke, ind)
    local names = direction == 0 and request_ids or reply_ids
    local text = (names[ak] or ("AK " .. ak))
    if not (ak == 0) then text = text .. string.format(" P%04d", pnu) end
    local sub = bit.band(ind, 0xFF)
    local indexed = direction == 0 and { [4] = true, [6] = true, [7] = true, [8] = true,
      [11] = true, [12] = true } or { [3] = true, [4] = true, [5] = true }
    if indexed[ak] then text = text .. "[" .. sub .. "]" end
    if direction == 1 and ak == 7 then
      text = text .. ": error " .. tvb(at + 2 * (pkw - 1), 2):uint()
    end
    p:add(f.parameter, tvb(at, pkw * 2), text)
    if ak ~= 0 then info = info .. " " .. text end
    at = at + pkw * 2
  end
  for i = 0, pzd_words - 1 do
    if at + 2 > 8 + t - 1 then break end
    local w = tvb(at, 2)
    if i == 0 and direction == 0 then
      root:add(f.stw1, w):append_text(" (" .. named_bits(w:uint(), stw1_bits) .. ")")
      info = info .. string.format(" STW1 0x%04X", w:uint())
    elseif i == 0 then
      root:add(f.zsw1, w):append_text(" (" .. named_bits(w:uint(), zsw1_bits) .. ")")
      info = info .. string.format(" ZSW1 0x%04X", w:uint())
    elseif i == 1 and direction == 0 then
      root:add(f.hsw, w):append_text(string.format(" (%.1f %%)", w:int() * 100 / 16384))
    elseif i == 1 then
      root:add(f.hiw, w):append_text(string.format(" (%.1f %%)", w:int() * 100 / 16384))
    else
      root:add(f.pzd, w)
    end
    at = at + 2
  end
  local bcc = 0
  for i = 8, 8 + t - 2 do bcc = bit.bxor(bcc, tvb(i, 1):uint()) end
  local bccitem = root:add(f.bcc, tvb(8 + t - 1, 1))
  bccitem:add(f.bcc_ok, tvb(8 + t - 1, 1), bcc == tvb(8 + t - 1, 1):uint())
  if bcc ~= tvb(8 + t - 1, 1):uint() then
    bccitem:append_text(string.format(" (expected 0x%02X)", bcc))
  end
  pinfo.cols.info = info
  return tvb:len()
end

DissectorTable.get("wtap_encap"):add(wtap.USER0, uss)
